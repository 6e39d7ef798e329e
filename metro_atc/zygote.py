"""Fork server ("zygote") for the graph's node processes: import once, fork each node.

Every node process of ``python -m metro_atc run`` used to import rclpy, numpy, numba and its
node module and set up numba's CPU target by itself (~0.6-0.9 s of CPU each), all five at
once on a 2-core machine. The zygote does that once, before any rclpy context or DDS
participant exists, then forks each node process on request; the child runs the node
executable's own entry point (the installed ``console_scripts`` one, with the node's command
line as ``sys.argv``), so a forked node runs the same code as an exec'd one.

Protocol (one JSON object per line): the zygote writes ``{"ready": ...}`` on its stdout once
preloaded (or ``{"error": ...}`` and exits); then, for every request read on its stdin
``{"argv": [...], "log": path, "mode": "wb"|"ab", "parent": pid}``, it forks an intermediate
process that forks the node and exits, so that the node is re-parented to ``parent`` (the
launcher, a child subreaper: :func:`become_subreaper`), and answers ``{"pid": n}``. The node
starts its own session, has stdout/stderr on its log and stdin on /dev/null, and waits until
its parent is ``parent`` before it starts (the launcher's :data:`PARENT_PID_ENV` watch).
EOF on stdin ends the zygote.

Safety: a fork copies only the calling thread. The zygote refuses to serve (answers an
error; the launcher then execs the nodes as before) if a Python thread other than the main
one runs or an rclpy context was initialised. Native threads started by library loads stay
(OpenBLAS's pool, which re-creates itself after a fork; LTTng-UST's two registration
threads, started by the ROS tracing library when rclpy loads, idle without a session
daemon): :func:`fork_safety` reports them.

ROS-free at import (the launcher imports it); rclpy and the node modules load in
:func:`preload`.
"""

from __future__ import annotations

import ctypes
import importlib
import json
import os
import sys
import threading
import time
from typing import Any, Callable, Sequence

DIST = "metro-atc"
"""The distribution whose ``console_scripts`` entry points are the node executables."""
PR_SET_CHILD_SUBREAPER = 36
"""prctl option (Linux >= 3.4): orphaned descendants are re-parented to this process."""
REPARENT_WAIT_S = 5.0
"""How long [s] a forked node waits to be re-parented to the launcher before it gives up."""


def become_subreaper() -> bool:
    """Make this process a child subreaper (Linux); True on success."""
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        return int(libc.prctl(PR_SET_CHILD_SUBREAPER, 1, 0, 0, 0)) == 0
    except (OSError, AttributeError):
        return False


def entry_point(name: str) -> Callable[[], Any]:
    """The ``console_scripts`` entry point ``name`` of :data:`DIST` (what the script runs)."""
    from importlib.metadata import distribution

    for ep in distribution(DIST).entry_points:
        if ep.group == "console_scripts" and ep.name == name:
            fn: Callable[[], Any] = ep.load()
            return fn
    raise LookupError(f"no console script {name!r} in {DIST}")


def native_threads() -> int:
    """Number of OS threads of this process (``/proc/self/task``)."""
    try:
        return len(os.listdir("/proc/self/task"))
    except OSError:
        return -1


def fork_safety() -> str | None:
    """Why this process must not fork nodes now (None: it may).

    A Python thread besides the main one, or an initialised rclpy context (DDS participant
    and its threads), would be copied half-way into the child.
    """
    if threading.active_count() != 1:
        names = ", ".join(t.name for t in threading.enumerate())
        return f"{threading.active_count()} Python threads ({names})"
    rclpy = sys.modules.get("rclpy")
    if rclpy is not None:
        try:
            if rclpy.ok():
                return "an rclpy context is initialised"
        except Exception as exc:  # noqa: BLE001 - an unknown state is not a safe one
            return f"rclpy state unknown: {exc}"
    return None


def warm_caller_lookup() -> None:
    """Fill :mod:`inspect`'s file -> module tables for every module loaded so far.

    rclpy's logger looks up its caller (``inspect.getframeinfo``) at a node's first log
    call, and :func:`inspect.getmodule` then resolves the real path of every loaded module
    once per process (~900 modules: ~0.035 s of CPU in each node, measured on a loaded
    2-core machine); done here once, the forked nodes inherit the tables and only look up
    modules loaded after the fork.
    """
    import inspect

    inspect.getframeinfo(sys._getframe())


def preload(executables: Sequence[str]) -> dict[str, Any]:
    """Import rclpy and the given node executables' modules; set up numba's CPU target.

    Returns what was done: ``cpu_s`` (process CPU time so far [s]), ``wall_s`` (time spent
    here [s]), ``modules`` (node modules loaded), ``package`` (``metro_atc``'s location).
    """
    t0 = time.monotonic()
    import rclpy  # noqa: F401 - the children inherit it loaded
    import rclpy.executors  # noqa: F401
    import rclpy.node  # noqa: F401

    loaded = []
    for name in executables:
        fn = entry_point(name)
        loaded.append(fn.__module__)
    if "numba" in sys.modules:
        # numba's first kernel call in a process loads the CPU target's extra registries
        # (numba.np.arraymath and friends, ~0.2-0.45 s of CPU); once here for all children
        from numba.core.registry import cpu_target
        cpu_target.target_context.refresh()
    warm_caller_lookup()
    pkg = importlib.import_module("metro_atc")
    return {"cpu_s": round(time.process_time(), 3), "wall_s": round(time.monotonic() - t0, 3),
            "modules": loaded, "package": os.path.dirname(os.path.abspath(pkg.__file__ or ""))}


def _write(obj: dict[str, Any]) -> None:
    sys.stdout.write(json.dumps(obj) + "\n")
    sys.stdout.flush()


def _request(line: str) -> tuple[list[str], str, str, int]:
    """Validate one request line; (argv, log path, open mode, parent pid) or ValueError."""
    req = json.loads(line)
    if not isinstance(req, dict):
        raise ValueError("a request is a JSON object")
    argv, log, mode, parent = req["argv"], req["log"], req.get("mode", "wb"), req["parent"]
    if not (isinstance(argv, list) and argv and all(isinstance(x, str) for x in argv)):
        raise ValueError("argv must be a non-empty list of strings")
    if not isinstance(log, str) or mode not in ("wb", "ab") or not isinstance(parent, int):
        raise ValueError("bad log, mode or parent")
    return argv, log, mode, parent


def _open_log(log: str, mode: str) -> int:
    """The node's log file, opened for writing (``mode`` ``"ab"``: appended to)."""
    return os.open(log, os.O_WRONLY | os.O_CREAT | (os.O_APPEND if mode == "ab" else
                                                    os.O_TRUNC), 0o644)


def _child(argv: list[str], fd: int, parent: int) -> list[str]:
    """In the forked node: session, stdio, re-parenting; return argv to run.

    ``fd``: the node's log (stdout and stderr), opened before the fork.
    """
    os.setsid()
    null = os.open(os.devnull, os.O_RDONLY)
    os.dup2(null, 0)
    os.dup2(fd, 1)
    os.dup2(fd, 2)
    os.close(fd)
    os.close(null)
    end = time.monotonic() + REPARENT_WAIT_S
    while os.getppid() != parent:
        if time.monotonic() > end:
            os.write(2, f"zygote: not re-parented to {parent}\n".encode())
            os._exit(1)
        time.sleep(0.001)
    return argv


def serve(stdin: Any = None) -> list[str] | None:
    """Answer fork requests until EOF; in a forked node return its argv (else None)."""
    stdin = sys.stdin if stdin is None else stdin
    for line in stdin:
        if not line.strip():
            continue
        try:
            argv, log, mode, parent = _request(line)
        except (ValueError, KeyError, TypeError) as exc:
            _write({"error": f"bad request: {exc}"})
            continue
        problem = fork_safety()
        if problem:
            _write({"error": f"not forking: {problem}"})
            continue
        r, w = os.pipe()
        sys.stdout.flush()
        sys.stderr.flush()
        mid = os.fork()
        if mid == 0:  # intermediate: fork the node, hand its pid over, leave at once
            os.close(r)
            try:
                # the log exists once the pid is answered (as an exec'd node's, which the
                # launcher opens before starting it): a reader may look at once
                fd = _open_log(log, mode)
                pid = os.fork()
            except OSError:
                os._exit(1)
            if pid == 0:
                os.close(w)
                return _child(argv, fd, parent)
            os.write(w, str(pid).encode())
            os._exit(0)
        os.close(w)
        with os.fdopen(r, "rb") as fh:
            raw = fh.read()
        os.waitpid(mid, 0)
        try:
            _write({"pid": int(raw)})
        except ValueError:
            _write({"error": "fork failed"})
    return None


class Forked:
    """A node process forked by the zygote and re-parented to this process (``Popen``-like).

    ``pid``, ``returncode`` (None while it runs; negative: killed by that signal),
    :meth:`poll` and :meth:`wait` as :class:`subprocess.Popen` has them.
    """

    def __init__(self, pid: int) -> None:
        """Track child ``pid`` (it must be a child of this process)."""
        self.pid = pid
        self.returncode: int | None = None

    def poll(self) -> int | None:
        """The exit code if the process has ended (reaps it), else None."""
        if self.returncode is None:
            try:
                pid, status = os.waitpid(self.pid, os.WNOHANG)
            except ChildProcessError:  # reaped elsewhere: its status is lost
                self.returncode = 255
                return self.returncode
            if pid == self.pid:
                self.returncode = os.waitstatus_to_exitcode(status)
        return self.returncode

    def wait(self, timeout: float | None = None) -> int:
        """Wait for the end (``subprocess.TimeoutExpired`` after ``timeout`` [s])."""
        import subprocess

        end = None if timeout is None else time.monotonic() + timeout
        delay = 0.001
        while self.poll() is None:
            if end is not None and time.monotonic() >= end:
                raise subprocess.TimeoutExpired(str(self.pid), timeout or 0.0)
            time.sleep(delay)
            delay = min(delay * 2, 0.02)
        assert self.returncode is not None
        return self.returncode


class Client:
    """The launcher's side: start the zygote, ask it for node processes.

    :meth:`spawn` returns a :class:`Forked` or None (no zygote, or it refused: the caller
    then execs the node as before); after one failure the zygote is not asked again.
    """

    def __init__(self, executables: Sequence[str], env: dict[str, str],
                 ready_timeout_s: float = 60.0) -> None:
        """Start ``python -P -m metro_atc.zygote EXECUTABLES`` (preloading at once).

        ``env``: the environment of the zygote and so of every node it forks. This process
        becomes a child subreaper; without that (not Linux) no zygote is started.
        """
        import subprocess

        self.info: dict[str, Any] = {}
        self.error = ""
        self.proc: subprocess.Popen[bytes] | None = None
        self.ready_timeout_s = float(ready_timeout_s)
        self._ready: bool | None = None
        if not become_subreaper():
            self.error = "no child subreaper (not Linux?)"
            return
        try:
            self.proc = subprocess.Popen(
                [sys.executable, "-P", "-m", "metro_atc.zygote", *executables],
                stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL,
                env=env, start_new_session=True)
        except OSError as exc:
            self.error = f"zygote not started: {exc}"

    def _read(self, timeout_s: float) -> dict[str, Any] | None:
        import select

        assert self.proc is not None and self.proc.stdout is not None
        fd = self.proc.stdout.fileno()
        if not select.select([fd], [], [], timeout_s)[0]:
            return None
        line = self.proc.stdout.readline()
        if not line:
            return None
        try:
            obj = json.loads(line)
        except ValueError:
            return None
        return obj if isinstance(obj, dict) else None

    def ready(self) -> bool:
        """Wait (once) for the zygote's preload; True if it serves."""
        if self._ready is None:
            self._ready = False
            if self.proc is not None:
                msg = self._read(self.ready_timeout_s)
                if msg is not None and msg.get("ready"):
                    self.info, self._ready = msg, True
                else:
                    self.error = str((msg or {}).get("error", "no answer"))
                    self.close()
        return bool(self._ready)

    def spawn(self, argv: Sequence[str], log: str, mode: str = "wb") -> Forked | None:
        """Fork a node running ``argv`` (stdout/stderr to ``log``); None if not served."""
        if not self.ready() or self.proc is None or self.proc.stdin is None:
            return None
        msg = self.send({"argv": list(argv), "log": str(log), "mode": mode,
                         "parent": os.getpid()})
        pid = None if msg is None else msg.get("pid")
        if not isinstance(pid, int):
            self.error = str((msg or {}).get("error", "no answer"))
            self.close()
            return None
        return Forked(pid)

    def send(self, request: Any, timeout_s: float = 30.0) -> dict[str, Any] | None:
        """Send one request line (any JSON value); the zygote's answer (None: none came)."""
        if not self.ready() or self.proc is None or self.proc.stdin is None:
            return None
        try:
            self.proc.stdin.write((json.dumps(request) + "\n").encode())
            self.proc.stdin.flush()
        except OSError as exc:
            self.error = f"zygote gone: {exc}"
            self.close()
            return None
        return self._read(timeout_s)

    def cpu_s(self) -> float | None:
        """CPU time [s] the zygote used (its preload), as the launcher reports per process."""
        return self.info.get("cpu_s") if self.info else None

    def release(self) -> None:
        """Tell the zygote to end (EOF on its stdin) without waiting; no more forks."""
        self._ready = False
        p = self.proc
        if p is not None and p.stdin is not None and not p.stdin.closed:
            try:
                p.stdin.close()
            except OSError:
                pass

    def close(self) -> None:
        """End the zygote (EOF on its stdin; SIGKILL if it does not go within 5 s)."""
        p, self.proc = self.proc, None
        self._ready = False
        if p is None:
            return
        try:
            if p.stdin is not None and not p.stdin.closed:
                p.stdin.close()
            p.wait(timeout=5.0)
        except Exception:  # noqa: BLE001 - best effort: it must not outlive the run
            p.kill()
            p.wait()
        if p.stdout is not None:
            p.stdout.close()
        try:  # the forked nodes are gone (reaped): orphans need not come here any more
            ctypes.CDLL(None).prctl(PR_SET_CHILD_SUBREAPER, 0, 0, 0, 0)
        except (OSError, AttributeError):
            pass


def main(argv: Sequence[str] | None = None) -> int:
    """``python -P -m metro_atc.zygote EXECUTABLE...``: preload, then serve (see module doc)."""
    names = list(sys.argv[1:] if argv is None else argv)
    try:
        info = preload(names)
    except Exception as exc:  # noqa: BLE001 - reported to the launcher, which execs instead
        _write({"error": f"preload failed: {type(exc).__name__}: {exc}"})
        return 1
    problem = fork_safety()
    if problem:
        _write({"error": f"not forking: {problem}"})
        return 1
    info.update(ready=True, native_threads=native_threads())
    _write(info)
    node_argv = serve()
    if node_argv is None:
        # nothing to clean up (no files, no DDS): skip the interpreter's teardown of ~1 000
        # modules (~1 s of CPU on a loaded machine, after the graph stopped)
        sys.stdout.flush()
        os._exit(0)
    # the forked node: run its executable's entry point as the installed script does
    sys.argv = node_argv
    name = os.path.basename(node_argv[0])
    return exit_process(int(entry_point(name)() or 0))


def flush_open_files() -> int:
    """Flush every open writable Python file object; return how many were flushed.

    What the interpreter's teardown does for the file objects it deallocates.
    """
    import gc
    import io

    n = 0
    for obj in gc.get_objects():
        if isinstance(obj, io.IOBase):
            try:
                if not obj.closed and obj.writable():
                    obj.flush()
                    n += 1
            except (OSError, ValueError):
                pass
    return n


def exit_process(code: int) -> int:
    """End a forked node now: atexit handlers, flushed files, then ``os._exit(code)``.

    The interpreter's own teardown of ~1 000 modules took ~0.5-2.5 s of wall time per node
    process (more with the machine busy), after the node had closed its outputs, destroyed
    its nodes and its rclpy context (DDS participant). Returns ``code`` (the normal exit)
    instead if a non-daemon thread runs: the interpreter waits for those.
    """
    import atexit

    main_thread = threading.main_thread()
    if any(t is not main_thread and not t.daemon and t.is_alive()
           for t in threading.enumerate()):
        return code
    atexit._run_exitfuncs()
    flush_open_files()
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError, AttributeError):
            pass
    os._exit(code)


if __name__ == "__main__":
    raise SystemExit(main())
