"""Test harness: start installed node executables, probe their topics over DDS."""

from __future__ import annotations

import contextlib
import fcntl
import os
import signal
import subprocess
import tempfile
import threading
import time
from pathlib import Path
from typing import Any, Callable, Iterator, Sequence

ROOT = Path(__file__).resolve().parent.parent
INSTALLED = ROOT / "install" / "metro_atc" / "lib" / "metro_atc"


class DomainAllocator:
    """Hands out DDS domain ids that no other test (or concurrent pytest run) holds.

    Uses lock files in the temp directory; ids 30..229 (Fast DDS supports 0..232).
    """

    def __init__(self, lo: int = 30, hi: int = 229) -> None:
        """Set the id range."""
        self.lo, self.hi = lo, hi
        self.dir = Path(tempfile.gettempdir()) / "metro_atc_domains"
        self.dir.mkdir(exist_ok=True)
        self._next = lo + (os.getpid() * 7) % (hi - lo)

    @contextlib.contextmanager
    def allocate(self) -> Iterator[int]:
        """Lock and yield a free domain id."""
        for k in range(self.hi - self.lo + 1):
            dom = self.lo + (self._next - self.lo + k) % (self.hi - self.lo + 1)
            fh = open(self.dir / f"{dom}.lock", "w")
            try:
                fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except OSError:
                fh.close()
                continue
            self._next = dom + 1
            try:
                yield dom
            finally:
                fcntl.flock(fh, fcntl.LOCK_UN)
                fh.close()
            return
        raise RuntimeError("no free ROS_DOMAIN_ID for the test")


class NodeProcess:
    """A node executable running as a subprocess (own process group), logging to a file."""

    def __init__(self, argv: Sequence[str], env: dict[str, str], log_path: Path) -> None:
        """Start the process."""
        self.argv = list(argv)
        self.log_path = log_path
        self._log = open(log_path, "wb")
        env = dict(env, RCUTILS_LOGGING_BUFFERED_STREAM="0", PYTHONUNBUFFERED="1")
        self.proc = subprocess.Popen(self.argv, env=env, stdout=self._log,
                                     stderr=subprocess.STDOUT, start_new_session=True)

    @classmethod
    def installed(cls, name: str, ros_args: Sequence[str], env: dict[str, str],
                  log_dir: Path) -> "NodeProcess":
        """Start ``install/metro_atc/lib/metro_atc/<name>`` with ``--ros-args ...``."""
        argv = [str(INSTALLED / name), "--ros-args", *ros_args]
        return cls(argv, env, log_dir / f"{name}_{time.monotonic_ns()}.log")

    @property
    def pid(self) -> int:
        """Process id."""
        return self.proc.pid

    def alive(self) -> bool:
        """True while the process runs."""
        return self.proc.poll() is None

    def log(self) -> str:
        """Everything the process printed so far."""
        if not self._log.closed:
            self._log.flush()
        return self.log_path.read_text(errors="replace")

    def wait_for_log(self, text: str, timeout: float = 20.0) -> bool:
        """Wait until ``text`` appears in the log."""
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            if text in self.log():
                return True
            if not self.alive():
                return text in self.log()
            time.sleep(0.05)
        return False

    def wait(self, timeout: float) -> int | None:
        """Wait for exit; return the exit code or None on timeout."""
        try:
            return self.proc.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            return None

    def stop(self, sig: int = signal.SIGINT, grace: float = 5.0) -> int:
        """Stop by PID: ``sig`` to the process group, SIGKILL after ``grace`` seconds."""
        if self.alive():
            with contextlib.suppress(ProcessLookupError):
                os.killpg(self.proc.pid, sig)
            try:
                self.proc.wait(timeout=grace)
            except subprocess.TimeoutExpired:
                with contextlib.suppress(ProcessLookupError):
                    os.killpg(self.proc.pid, signal.SIGKILL)
                self.proc.wait()
        self._log.close()
        return int(self.proc.returncode)


class TopicProbe:
    """An rclpy node in the test process, on its own context and domain, spun in a thread."""

    def __init__(self, domain_id: int, name: str = "test_probe") -> None:
        """Create the context, node and executor thread."""
        import rclpy
        from rclpy.context import Context
        from rclpy.executors import SingleThreadedExecutor

        self.ctx = Context()
        rclpy.init(context=self.ctx, domain_id=domain_id)
        self.node = rclpy.create_node(name, context=self.ctx)
        self.executor = SingleThreadedExecutor(context=self.ctx)
        self.executor.add_node(self.node)
        self.lock = threading.Lock()
        self.received: dict[str, list[Any]] = {}
        self._stop = False
        self.thread = threading.Thread(target=self._spin, daemon=True)
        self.thread.start()

    def _spin(self) -> None:
        while not self._stop and self.ctx.ok():
            try:
                self.executor.spin_once(timeout_sec=0.05)
            except Exception:  # noqa: BLE001 - context shut down under us
                break

    def subscribe(self, msg_type: Any, topic: str, qos: Any) -> list[Any]:
        """Record every message on ``topic``; return the (live) list."""
        buf: list[Any] = []
        with self.lock:
            self.received[topic] = buf

        def cb(m: Any) -> None:
            with self.lock:
                buf.append(m)
        self.node.create_subscription(msg_type, topic, cb, qos)
        return buf

    def publisher(self, msg_type: Any, topic: str, qos: Any) -> Any:
        """Create a publisher on the probe node."""
        return self.node.create_publisher(msg_type, topic, qos)

    def wait_for(self, pred: Callable[[], bool], timeout: float = 20.0) -> bool:
        """Poll ``pred`` until true or timeout."""
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            with self.lock:
                if pred():
                    return True
            time.sleep(0.02)
        with self.lock:
            return bool(pred())

    def close(self) -> None:
        """Stop spinning and shut the context down."""
        self._stop = True
        self.thread.join(timeout=2.0)
        self.executor.shutdown()
        self.node.destroy_node()
        self.ctx.try_shutdown()
