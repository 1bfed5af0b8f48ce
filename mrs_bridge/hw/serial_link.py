"""One serial link: a thread that owns a serial port, reconnects with back-off and reports its state.

The hardware drivers (``p2os``: Pioneer P2OS/ARCOS; ``hokuyo``: SCIP 2.0 lasers) share the same
life of a serial device, as Player's serial drivers each re-implemented it: open the port (pyserial),
talk the device's protocol until it goes silent or the port fails, close, wait, open again -- the
wait doubling from ``reconnect`` up to ``max_backoff`` while the device stays away, back to
``reconnect`` once it answered. What is said on the line is the driver's: a *session* callable run on
this thread with the link, using :meth:`SerialLink.read`, :meth:`write`, :meth:`write_pending` and
:meth:`up`, and returning (or raising) why the session ended. The codecs it uses are pure
(:mod:`mrs_bridge.hw.p2os`, :mod:`mrs_bridge.hw.scip`).

Between the threads only two deques pass (``collections.deque`` appends and pops are atomic): the
scheduler reads events from ``inbox`` in its ``update()`` -- ``("lost", why)`` from the link, the
rest as the session posts them -- and queues frames to write with :meth:`send`. The scheduler never
touches the port and never waits for the device; :meth:`stop` writes the final frames queued
(motors off) before the port closes.
"""

from __future__ import annotations

import collections
import threading
import time
from collections.abc import Callable, Iterable

from rsal.errors import RsalError

__all__ = ["SerialLink"]

Session = Callable[["SerialLink"], str | None]


class SerialLink(threading.Thread):
    """The thread owning serial ``port`` at ``baud``; ``session(link)`` speaks the protocol."""

    def __init__(
        self,
        port: str,
        baud: int,
        session: Session,
        *,
        name: str,
        reconnect: float,
        max_backoff: float,
        read_timeout: float = 0.02,
        write_timeout: float = 0.5,
        close_with: bytes = b"",
        inbox_size: int | None = None,
    ) -> None:
        super().__init__(name=name, daemon=True)
        self.port, self.baud, self.session = port, baud, session
        self.reconnect, self.max_backoff = reconnect, max_backoff
        self.read_timeout, self.write_timeout = read_timeout, write_timeout
        self.close_with = close_with  # written before every close (Hokuyo: QT, laser off)
        #: events for the scheduler: ("lost", why) from the link, the session's own
        self.inbox: collections.deque = collections.deque(maxlen=inbox_size)
        self.outbox: collections.deque = collections.deque()  # frames to write
        self.stop_event = threading.Event()
        #: whether the device answers (set by the session's :meth:`up`, cleared when it ends)
        self.connected = False
        self.answered = False  # the current connection got as far as :meth:`up`
        self.sessions = 0
        self.ser = None

    # ------------------------------------------------------------------ the scheduler's side
    def send(self, data: bytes) -> None:
        """Queue a frame for the device (dropped while it does not answer)."""
        if self.connected:
            self.outbox.append(data)

    def stop(self, final: Iterable[bytes] = (), timeout: float = 1.0) -> None:
        """Write ``final`` (if connected), close the port and end the thread."""
        if self.connected:
            self.outbox.extend(final)
        self.stop_event.set()
        if self.is_alive():
            self.join(timeout)

    # ------------------------------------------------------------------ the session's side
    @property
    def stopping(self) -> bool:
        return self.stop_event.is_set()

    def up(self, *event) -> None:
        """The device answered: commands are accepted from now on; ``event`` goes to the inbox."""
        self.connected = True
        self.answered = True
        if event:
            self.inbox.append(event)

    def post(self, *event) -> None:
        self.inbox.append(event)

    def read(self) -> bytes:
        """What has arrived (at least one byte, or nothing after the read timeout)."""
        return self.ser.read(max(1, self.ser.in_waiting))

    def write(self, data: bytes) -> None:
        self.ser.write(data)

    def write_pending(self) -> None:
        """Write the frames the scheduler queued."""
        while self.outbox:
            self.ser.write(self.outbox.popleft())

    def reset_input(self) -> None:
        self.ser.reset_input_buffer()

    # ------------------------------------------------------------------ the thread
    def _open(self):
        import serial

        return serial.Serial(self.port, self.baud, timeout=self.read_timeout, write_timeout=self.write_timeout)

    def run(self) -> None:
        backoff = self.reconnect
        while not self.stop_event.is_set():
            self.answered = False
            why = self._one_session()
            self.connected = False
            if self.stop_event.is_set():
                break
            self.inbox.append(("lost", why))
            if self.answered:  # it worked until now: retry soon
                backoff = self.reconnect
            if self.stop_event.wait(backoff):
                break
            backoff = min(backoff * 2.0, self.max_backoff)

    def _one_session(self) -> str:
        try:
            self.ser = self._open()
        except Exception as e:  # SerialException, OSError: port missing, busy, no permission
            return f"cannot open {self.port}: {e}"
        self.sessions += 1
        self.outbox.clear()
        try:
            return self.session(self) or "stopped"
        except (RsalError, TimeoutError) as e:  # the protocol's own words
            return str(e)
        except Exception as e:  # the port went away under us
            return f"{self.port}: {type(e).__name__}: {e}"
        finally:
            self._close()

    def _close(self) -> None:
        ser, self.ser = self.ser, None
        if ser is None:
            return
        try:
            if self.stop_event.is_set():
                while self.outbox:  # the final frames (motors off)
                    ser.write(self.outbox.popleft())
            if self.close_with:
                ser.write(self.close_with)
            ser.flush()
        except Exception:
            pass
        try:
            ser.close()
        except Exception:
            pass

    def wait_until(self, deadline: float) -> bool:
        """Whether ``deadline`` (time.monotonic) is still ahead and the link is not stopping."""
        return time.monotonic() < deadline and not self.stop_event.is_set()
