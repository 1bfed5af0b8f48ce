"""The fleet dispatcher (issue: energy and a fleet dispatcher): tasks bid for within a window,
awarded by cost, re-bid when a robot fails, re-assigned, and battery-aware charging.

:mod:`.tasks` holds the task model and the typed messages, :mod:`.core` the dispatcher's logic (no
network), :mod:`.bidder` a robot's cost model, :mod:`.agent` the agents that put them on the fabric.
See ``docs/dispatch.md``.
"""

from .bidder import Bid, Energy, plan_bid
from .core import FINISHING, ChargePolicy, Charger, Dispatcher, RobotRecord, TaskRecord
from .tasks import (
    KINDS,
    DispatchMsg,
    FleetMsg,
    Refusal,
    Task,
    TaskRefused,
    TaskRequest,
    TaskState,
    TaskStatus,
    parse_task,
    task_places,
)

__all__ = [
    "KINDS",
    "FINISHING",
    "Bid",
    "Charger",
    "ChargePolicy",
    "DispatchMsg",
    "Dispatcher",
    "Energy",
    "FleetMsg",
    "Refusal",
    "RobotRecord",
    "Task",
    "TaskRecord",
    "TaskRefused",
    "TaskRequest",
    "TaskState",
    "TaskStatus",
    "parse_task",
    "plan_bid",
    "task_places",
]
