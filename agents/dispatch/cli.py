"""``rsal task``: submit, list and cancel dispatcher tasks from the command line.

``rsal task submit KIND --arg KEY=VALUE ... [--robot AGENT] [--follow]`` sends a ``task_request``
to the fabric's :class:`agents.dispatch.agent.DispatcherAgent` and prints the task's states on
``task_state`` (the first one, or every one until it ends with ``--follow``); ``rsal task list``
prints every task the dispatcher knows; ``rsal task cancel ID`` cancels one. A refused task prints
the dispatcher's one line and exits 1. The command runs as a short-lived agent (``task-cli-<pid>``)
so its messages carry a sender like any agent's.
"""

from __future__ import annotations

import argparse
import asyncio
import os
import sys

from rsal.cliutil import positive
from rsal.clock import wait_for
from rsal.transport import TransportArgs, add_transport_args

from ..runtime import Agent, AgentHost
from ..services import Message
from .client import cancel_request, list_request, submit_request
from .tasks import KINDS, TaskRequest, TaskState, TaskStatus

__all__ = ["register", "main"]


def _fail(text: str) -> int:
    print(f"rsal task: {text}", file=sys.stderr, flush=True)
    return 1


def _line(s: TaskStatus) -> str:
    robot = s.robot or "-"
    extra = f"  {s.reason}" if s.reason else ""
    return f"{s.task_id:<12} {s.kind:<8} {s.state:<10} {robot:<12}{extra}  {s.text}".rstrip()


async def _run(args: argparse.Namespace) -> int:
    async with AgentHost.connect(TransportArgs.from_namespace(args)) as host:
        me = await host.start(Agent(f"task-cli-{os.getpid()}"))
        got: asyncio.Queue[tuple[str, TaskStatus]] = asyncio.Queue()

        def on_state(msg: Message) -> None:
            try:
                got.put_nowait((msg.conversation, TaskStatus.from_dict(msg.body)))
            except Exception:
                pass

        me.subscribe(TaskStatus.SERVICE, on_state)
        loop = asyncio.get_running_loop()
        deadline = loop.time() + args.wait
        while not any(h.cls == "DispatcherAgent" for h in await host.who_is_there(0.5)):
            if loop.time() >= deadline:
                return _fail(
                    f"no DispatcherAgent answered within {args.wait:g} s; start one "
                    "('rsal agent DispatcherAgent') or check the endpoint (--connect)"
                )
        if args.op == "list":
            conv = me.publish(TaskRequest.SERVICE, list_request())
            rows: dict[str, TaskStatus] = {}
            while True:
                try:
                    c, st = await wait_for(got.get(), 1.0)
                except TimeoutError:
                    break
                if c == conv:
                    rows[st.task_id] = st
            for st in rows.values():
                print(_line(st), flush=True)
            if not rows:
                print("no tasks", flush=True)
            return 0
        if args.op == "cancel":
            tid = args.task_id
            me.publish(TaskRequest.SERVICE, cancel_request(tid))
        else:
            req = submit_request(args.kind, dict(args.arg or []), args.robot or "", args.id or "")
            tid = req.task["id"]
            me.publish(TaskRequest.SERVICE, req)
        while True:
            follow = getattr(args, "follow", False)
            left = deadline - loop.time() if not follow else None
            try:
                _, st = await wait_for(got.get(), left if left is None or left > 0 else 0.01)
            except TimeoutError:
                return _fail(f"no answer about task {tid} within {args.wait:g} s")
            if st.task_id not in (tid, "?") or (st.task_id == "?" and st.requester != me.id):
                continue
            state = TaskState(st.state)
            if state is TaskState.REFUSED:
                return _fail(f"refused ({st.reason}): {st.text}")
            print(_line(st), flush=True)
            if args.op == "cancel" and state is TaskState.CANCELLED:
                return 0
            if args.op == "submit" and (not follow or state.final):
                return 0 if state is not TaskState.FAILED else 1


def _arg(text: str) -> tuple[str, object]:
    from ..scenario import ScenarioError, parse_set

    try:
        ((k, v),) = parse_set([text]).items()
    except ScenarioError as e:
        raise argparse.ArgumentTypeError(str(e).replace("--set", "--arg")) from None
    return k, v


def main(args: argparse.Namespace) -> int:
    try:
        return asyncio.run(_run(args))
    except ValueError as e:  # the session could not be opened
        return _fail(str(e))
    except KeyboardInterrupt:
        return 130


def register(sub) -> None:
    p = sub.add_parser("task", help="submit, list or cancel tasks of the fleet dispatcher")
    ops = p.add_subparsers(dest="op", metavar="OP", required=True)
    s = ops.add_parser("submit", help="submit a task: rsal task submit go_to --arg x=1 --arg y=2")
    s.add_argument("kind", metavar="KIND", help=f"task kind: {', '.join(KINDS)}")
    s.add_argument(
        "--arg", action="append", type=_arg, metavar="KEY=VALUE", help="a task argument (YAML value: 2, [1, 2])"
    )
    s.add_argument("--robot", help="assign directly to this robot agent (no bidding)")
    s.add_argument("--id", help="task id (default: a fresh one)")
    s.add_argument("--follow", action="store_true", help="print every state until the task ends")
    lst = ops.add_parser("list", help="list the dispatcher's tasks")
    c = ops.add_parser("cancel", help="cancel a task")
    c.add_argument("task_id", metavar="ID")
    for q in (s, lst, c):
        q.add_argument("--wait", type=positive, default=10.0, help="seconds to wait for the dispatcher (default 10)")
        add_transport_args(q)
        q.set_defaults(func=main)
