"""Six mock encoders in another process, on a python-can interface both processes reach
(``udp_multicast``; SocketCAN ``vcan`` where the kernel has it): the driver then meets its
encoders as on a real rig — through an interface's own delivery, echo and timestamp rules,
not python-can's in-process virtual bus, and with no thread of the driver's process serving
them.

:class:`EncoderProcess` starts ``python -m hexcal.mock_hw.can_process`` and drives it over the
child's standard input and output, one JSON object a line (no pickle: the child takes nothing
but these requests). The child builds a :class:`~hexcal.mock_hw.robot.MockRobot` of the
left-hand design from ``robot_seed`` and :class:`~hexcal.mock_hw.can_encoders.MockEncoderNodes`
from the configuration, answers ``{"call": name, "args": [...]}`` with ``{"ok": result}`` or
``{"error": text}``, and stops on ``{"call": "stop"}`` or when its input closes (the parent
died). The calls are the mock's own (:data:`CALLS`): faults, what it latched, its nodes' state,
and ``move_to`` for the robot.

The parent keeps a twin of the robot (same design and seed) for what the tests compute from it
(the true pose, the simulator's readings); :meth:`EncoderProcess.move_to` moves both.
"""

from __future__ import annotations

import contextlib
import json
import os
import selectors
import subprocess
import sys
import tempfile
from collections.abc import Callable, Mapping
from pathlib import Path
from types import TracebackType
from typing import Any

import numpy as np

from hexcal.drivers.can_config import CanBusConfig

#: How long the child may take to start (imports, bus, boot-up of six nodes), s.
START_TIMEOUT_S = 30.0
#: How long one call may take, s.
CALL_TIMEOUT_S = 10.0


def _calls(nodes: Any, robot: Any) -> dict[str, Callable[..., Any]]:
    """The requests the child serves: name → function of JSON arguments, JSON result."""
    return {
        "silence": lambda leg, silent=True: nodes.silence(leg, silent),
        "drop_next": lambda leg, n=1: nodes.drop_next(leg, n),
        "reboot": lambda leg, shift=0.0: nodes.reboot(leg, shift),
        "emergency": lambda leg, code, register=1: nodes.emergency(leg, code, register),
        "set_jitter": lambda s: setattr(nodes, "jitter_s", float(s)),
        "latched": lambda: [[c, r.tolist()] for c, r in nodes.latched().items()],
        "states": lambda: [[leg, st] for leg, st in nodes.states.items()],
        "nmt_log": lambda: [list(e) for e in nodes.nmt_log],
        "syncs_seen": lambda: nodes.syncs_seen,
        "value": lambda leg, index, sub=0: nodes.encoders[leg].value(index, sub),
        "move_to": lambda p, r: robot.move_to(np.array(p), np.array(r)),
    }


#: The calls the child serves.
CALLS = tuple(_calls(None, None))


def _serve(spec: dict[str, Any]) -> None:
    """The child: build the robot and the nodes, then answer requests until told to stop."""
    from hexcal.mock_hw.can_encoders import MockEncoderNodes
    from hexcal.mock_hw.robot import DEFAULT_NOISE, MockRobot
    from hexcal.sim.robots import left_hand

    robot = MockRobot(left_hand(), noise=DEFAULT_NOISE, seed=int(spec["robot_seed"]))
    config = CanBusConfig.model_validate(spec["config"])
    eds = spec.get("eds")
    if isinstance(eds, dict):
        eds = {int(k): v for k, v in eds.items()}
    nodes = MockEncoderNodes(
        robot, config, seed=int(spec["seed"]), jitter_s=float(spec["jitter_s"]), eds=eds
    )
    calls = _calls(nodes, robot)
    out = sys.stdout
    with nodes:
        out.write(json.dumps({"ready": os.getpid()}) + "\n")
        out.flush()
        for line in sys.stdin:
            request = json.loads(line)
            name = request.get("call")
            if name == "stop":
                break
            try:
                if name not in calls:
                    raise KeyError(f"no call {name!r}; the calls are {', '.join(CALLS)}")
                reply = {"ok": calls[name](*request.get("args", []))}
            except Exception as exc:  # the parent reads it; the child serves on
                reply = {"error": f"{type(exc).__name__}: {exc}"}
            out.write(json.dumps(reply) + "\n")
            out.flush()


class EncoderProcess:
    """Six mock encoders of ``config`` in a child process (module docstring).

    ``robot_seed``, ``seed``, ``jitter_s``, ``eds`` as for :class:`MockRobot` and
    :class:`MockEncoderNodes` (``eds``: one path for all six, or {leg: path}). A context
    manager: the child is stopped — asked, then terminated, then killed — on exit, whatever
    happened. ``robot``: the parent's twin of the child's robot."""

    def __init__(
        self,
        config: CanBusConfig,
        *,
        robot_seed: int = 4,
        seed: int = 1,
        jitter_s: float = 0.0,
        eds: str | Path | Mapping[int, str | Path] | None = None,
    ):
        from hexcal.mock_hw.robot import DEFAULT_NOISE, MockRobot
        from hexcal.sim.robots import left_hand

        self.config = config
        self.robot = MockRobot(left_hand(), noise=DEFAULT_NOISE, seed=robot_seed)
        if isinstance(eds, Mapping):
            eds_spec: Any = {str(k): str(v) for k, v in eds.items()}
        else:
            eds_spec = None if eds is None else str(eds)
        self._spec = {
            "config": config.model_dump(mode="json"),
            "robot_seed": robot_seed,
            "seed": seed,
            "jitter_s": jitter_s,
            "eds": eds_spec,
        }
        self._proc: subprocess.Popen[str] | None = None
        self._stderr: Any = None
        self._sel: selectors.DefaultSelector | None = None
        self.pid: int | None = None

    # -- lifecycle -----------------------------------------------------------------------------
    def start(self) -> EncoderProcess:
        if self._proc is not None:
            return self
        self._stderr = tempfile.TemporaryFile(mode="w+")
        env = {**os.environ, "PYTHONUNBUFFERED": "1", "OPENBLAS_NUM_THREADS": "1"}
        self._proc = subprocess.Popen(
            [sys.executable, "-m", "hexcal.mock_hw.can_process"],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=self._stderr,
            text=True,
            env=env,
        )
        self._sel = selectors.DefaultSelector()
        assert self._proc.stdout is not None
        self._sel.register(self._proc.stdout, selectors.EVENT_READ)
        try:
            self._send(self._spec)
            self.pid = int(self._receive(START_TIMEOUT_S)["ready"])
        except BaseException:
            self.stop()
            raise
        return self

    def stop(self) -> None:
        """Stop the child (idempotent): ask, wait 5 s, terminate, wait 2 s, kill."""
        proc = self._proc
        if proc is None:
            return
        self._proc = None
        with contextlib.suppress(OSError, ValueError):
            assert proc.stdin is not None
            proc.stdin.write(json.dumps({"call": "stop"}) + "\n")
            proc.stdin.close()
        for stop, wait in ((None, 5.0), (proc.terminate, 2.0), (proc.kill, 2.0)):
            if stop is not None:
                stop()
            with contextlib.suppress(subprocess.TimeoutExpired):
                proc.wait(wait)
                break
        if proc.stdout is not None:
            proc.stdout.close()
        if self._sel is not None:
            self._sel.close()
        if self._stderr is not None:
            self._stderr.close()

    def __enter__(self) -> EncoderProcess:
        return self.start()

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.stop()

    @property
    def alive(self) -> bool:
        return self._proc is not None and self._proc.poll() is None

    # -- the wire ------------------------------------------------------------------------------
    def _send(self, message: dict[str, Any]) -> None:
        assert self._proc is not None and self._proc.stdin is not None
        self._proc.stdin.write(json.dumps(message) + "\n")
        self._proc.stdin.flush()

    def _receive(self, timeout: float) -> dict[str, Any]:
        assert self._proc is not None and self._proc.stdout is not None and self._sel is not None
        if not self._sel.select(timeout):
            raise RuntimeError(
                f"the encoder process (pid {self._proc.pid}) did not answer in {timeout:g} s"
                + self._child_said()
            )
        line = self._proc.stdout.readline()
        if not line:
            raise RuntimeError(
                f"the encoder process (pid {self._proc.pid}) ended" + self._child_said()
            )
        reply: dict[str, Any] = json.loads(line)
        return reply

    def _child_said(self) -> str:
        if self._stderr is None:
            return ""
        self._stderr.seek(0)
        tail = self._stderr.read()[-2000:]
        return f"; it wrote: {tail}" if tail else ""

    def call(self, name: str, *args: Any) -> Any:
        """Call ``name`` (one of :data:`CALLS`) in the child; its result."""
        if self._proc is None:
            raise RuntimeError("the encoder process is not running: start() it")
        self._send({"call": name, "args": list(args)})
        reply = self._receive(CALL_TIMEOUT_S)
        if "error" in reply:
            raise RuntimeError(f"the encoder process refused {name}: {reply['error']}")
        return reply.get("ok")

    # -- the mock's interface, as MockEncoderNodes has it -----------------------------------------
    def silence(self, leg: int, silent: bool = True) -> None:
        self.call("silence", leg, silent)

    def drop_next(self, leg: int, n: int = 1) -> None:
        self.call("drop_next", leg, n)

    def reboot(self, leg: int, zero_shift_mm: float = 0.0) -> None:
        self.call("reboot", leg, zero_shift_mm)

    def emergency(self, leg: int, code: int, register: int = 0x01) -> None:
        self.call("emergency", leg, code, register)

    @property
    def jitter_s(self) -> float:
        return float(self._spec["jitter_s"])

    @jitter_s.setter
    def jitter_s(self, value: float) -> None:
        self._spec["jitter_s"] = value
        self.call("set_jitter", value)

    def latched(self) -> dict[int, np.ndarray]:
        return {int(c): np.array(r) for c, r in self.call("latched")}

    @property
    def states(self) -> dict[int, int]:
        return {int(leg): int(st) for leg, st in self.call("states")}

    @property
    def nmt_log(self) -> list[tuple[int, int]]:
        return [(int(cs), int(node)) for cs, node in self.call("nmt_log")]

    @property
    def syncs_seen(self) -> int:
        return int(self.call("syncs_seen"))

    def value(self, leg: int, index: int, sub: int = 0) -> int:
        """Object ``index``:``sub`` as leg ``leg``'s node holds it."""
        return int(self.call("value", leg, index, sub))

    def move_to(self, position: np.ndarray, rotation: np.ndarray) -> None:
        """Move the child's robot and the twin here to the same pose."""
        self.robot.move_to(position, rotation)
        self.call("move_to", np.asarray(position).tolist(), np.asarray(rotation).tolist())


def main() -> None:
    """The child's entry: the spec on the first line of standard input, then requests."""
    import logging

    logging.basicConfig(level=logging.WARNING, stream=sys.stderr)
    line = sys.stdin.readline()
    if not line:
        return
    _serve(json.loads(line))


if __name__ == "__main__":
    main()


__all__ = ["CALLS", "EncoderProcess"]
