"""Executors: local worker processes (a forkserver pool whose workers die with the driver) or a
Dask cluster (a LocalCluster or a scheduler's address); both write each finished run's files as it
arrives and mark a worker that died as crashed."""

from __future__ import annotations

import os
import signal
import sys
import time
from pathlib import Path

from .runs import write_crashed, write_run
from .spec import SweepError
from .worker import _task, _warm_tasks, run_one, warm_cache


class _Progress:
    """A progress bar over runs on stderr: redrawn in place on a terminal, one line per finished
    run otherwise (logs, CI)."""

    def __init__(self, total: int, done: int, stream=sys.stderr):
        self.total, self.done, self.failed = total, done, 0
        self.stream = stream
        self.tty = stream.isatty()
        self.t0 = time.perf_counter()
        self.n_new = 0

    def update(self, run_id: str, status: str) -> None:
        self.done += 1
        self.n_new += 1
        if status != "converged":
            self.failed += 1
        el = time.perf_counter() - self.t0
        left = self.total - self.done
        eta = el / self.n_new * left if self.n_new else 0.0
        frac = self.done / self.total if self.total else 1.0
        bar = "#" * int(frac * 24)
        text = (f"[{bar:<24}] {self.done}/{self.total} runs, {self.failed} not converged, "
                f"{_hms(el)} elapsed, ~{_hms(eta)} left  {run_id} {status}")
        if self.tty:
            self.stream.write("\r" + text[:160].ljust(160))
        else:
            self.stream.write(text + "\n")
        self.stream.flush()

    def close(self) -> None:
        if self.tty:
            self.stream.write("\n")
            self.stream.flush()


def _hms(s: float) -> str:
    s = int(s)
    return f"{s // 3600}:{s // 60 % 60:02d}:{s % 60:02d}" if s >= 3600 else f"{s // 60}:{s % 60:02d}"


_THREAD_ENV = ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS")


PR_SET_PDEATHSIG = 1  # linux/prctl.h


def _die_with_parent() -> None:
    """Ask Linux to SIGKILL this process when its parent dies (prctl PR_SET_PDEATHSIG); a no-op
    elsewhere."""
    if not sys.platform.startswith("linux"):
        return
    try:
        import ctypes

        ctypes.CDLL(None, use_errno=True).prctl(PR_SET_PDEATHSIG, int(signal.SIGKILL), 0, 0, 0)
    except (OSError, AttributeError):
        pass


def _process_start(pid: int) -> str | None:
    """The start time of process pid (field 22 of /proc/pid/stat), None if gone or unknown."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    return stat[stat.rindex(")") + 2:].split()[19]


def _worker_init(driver_pid: int, driver_start: str | None, poll_s: float = 0.5) -> None:
    """Pool worker initializer: the worker dies with the sweep driver, however the driver ends.

    A local worker's parent is the forkserver, not the driver, so two guards: PR_SET_PDEATHSIG
    (the worker is killed when the forkserver dies) and a daemon thread that polls the driver's
    pid (with its start time, against pid reuse) and exits the worker when the driver is gone
    (kill -9 included). The thread runs between kernel calls: a worker notices within one
    solver iteration."""
    import threading

    _die_with_parent()

    def alive() -> bool:
        if driver_start is not None:
            return _process_start(driver_pid) == driver_start
        try:
            os.kill(driver_pid, 0)
            return True
        except ProcessLookupError:
            return False
        except PermissionError:
            return True

    def watch() -> None:
        while alive():
            time.sleep(poll_s)
        os._exit(1)

    threading.Thread(target=watch, name="clothsim-driver-watch", daemon=True).start()


def _local_pool(workers: int):
    import multiprocessing as mp
    from concurrent.futures import ProcessPoolExecutor

    # one thread per worker process (as Dask's nanny does), inherited by the spawned workers
    for k in _THREAD_ENV:
        os.environ.setdefault(k, "1")
    methods = mp.get_all_start_methods()
    if "forkserver" in methods:
        ctx = mp.get_context("forkserver")
        ctx.set_forkserver_preload(["clothsim.simulation", "clothsim.sweep"])
    else:
        ctx = mp.get_context("spawn")
    me = os.getpid()
    return ProcessPoolExecutor(max_workers=workers, mp_context=ctx, initializer=_worker_init,
                               initargs=(me, _process_start(me)))


def _run_local(todo, sweep, out, workers, on_done, on_warm):
    from concurrent.futures import as_completed
    from concurrent.futures.process import BrokenProcessPool

    pool = _local_pool(workers)
    futs = {}
    try:
        for t in _warm_tasks(todo, sweep):
            on_warm(pool.submit(warm_cache, t).result())
        futs = {pool.submit(run_one, _task(r, sweep)): r for r in todo}
        for fut in as_completed(futs):
            run = futs[fut]
            try:
                payload = fut.result()
            except BrokenProcessPool:
                write_crashed(out, run, "a worker process died (out of memory or killed?); rerun to retry")
                on_done(run, {"status": "crashed"})
                continue
            except Exception as exc:  # pickling or other infrastructure failure
                write_crashed(out, run, f"{type(exc).__name__}: {exc}")
                on_done(run, {"status": "crashed"})
                continue
            write_run(out, payload)
            on_done(run, payload)
    except BaseException:
        for f in futs:
            f.cancel()
        pool.shutdown(wait=False, cancel_futures=True)
        _terminate_pool(pool)
        raise
    pool.shutdown(wait=True)


def _terminate_pool(pool) -> None:
    """Stop our own worker processes at once (Ctrl-C, SIGTERM): only the pool's processes, by id;
    then the forkserver that started them, if this driver started one."""
    procs = getattr(pool, "_processes", None) or {}
    for p in list(procs.values()):
        try:
            p.terminate()
        except Exception:
            pass
    for p in list(procs.values()):
        try:
            p.join(timeout=2.0)
        except Exception:
            pass
    try:
        from multiprocessing import forkserver

        server = forkserver._forkserver
        pid = getattr(server, "_forkserver_pid", None)
        if pid:
            os.kill(pid, signal.SIGTERM)
            # reap it and forget it, so that the next pool of this process starts a fresh server
            # (a server still dying when the next pool asks for it answered with EOFError)
            server._stop()
    except (ImportError, AttributeError, ProcessLookupError, PermissionError, ChildProcessError, OSError):
        pass


class Terminated(KeyboardInterrupt):
    """SIGTERM or SIGHUP reached the sweep driver: it stops as on Ctrl-C (workers terminated,
    finished runs kept)."""


def _on_terminate(signum, frame):
    raise Terminated(signal.Signals(signum).name)


#: seconds to wait for a Dask scheduler to answer (--dask ADDRESS) before the sweep is refused: a
#: port that accepts connections and never answers (not a scheduler) used to hang the sweep
DASK_CONNECT_TIMEOUT_S = 15.0
#: the address schemes a remote Dask scheduler listens on
DASK_SCHEMES = ("tcp", "tls", "ws", "wss", "ucx")


def check_dask_address(address: str | None) -> None:
    """Refuse (SweepError naming --dask) an address that is neither ``local`` nor
    ``[SCHEME://]HOST:PORT`` with a scheme of DASK_SCHEMES and a port from 1 to 65535, before
    anything runs (``nonsense``, ``http://...``, ``tcp://[::1`` gave tracebacks)."""
    if address is None or address == "local":
        return
    hint = "give 'local' or a scheduler address tcp://HOST:PORT (e.g. tcp://127.0.0.1:8786)"
    try:
        from distributed.comm.addressing import parse_address, parse_host_port

        scheme, loc = parse_address(str(address), strict=False)
        host, port = parse_host_port(loc)
    except ImportError:
        raise SweepError("--dask: Dask is not installed (pip install 'dask[distributed]')") from None
    except (ValueError, TypeError) as exc:
        raise SweepError(f"--dask {address}: not a scheduler address ({exc}); {hint}") from None
    if scheme not in DASK_SCHEMES:
        raise SweepError(f"--dask {address}: unknown scheme '{scheme}' (a Dask scheduler speaks "
                         f"{', '.join(DASK_SCHEMES)}); {hint}")
    if not host or not isinstance(port, int) or not 1 <= port <= 65535:
        raise SweepError(f"--dask {address}: needs a host and a port from 1 to 65535; {hint}")


def _reach_scheduler(address: str, timeout: float = None) -> None:
    """Open (and close) a Dask connection to ``address`` within ``timeout`` seconds
    (DASK_CONNECT_TIMEOUT_S), handshake included: a port that accepts and never answers is
    refused with SweepError instead of hanging the sweep."""
    import asyncio

    from distributed.comm import connect

    timeout = DASK_CONNECT_TIMEOUT_S if timeout is None else timeout

    async def probe():
        # Dask's own timeout (it retries a refused connection) ends first and says why; the outer
        # one ends a connection accepted but never answered, where Dask's handshake waits on
        comm = await connect(address, timeout=0.8 * timeout)
        await comm.close()

    try:
        asyncio.run(asyncio.wait_for(probe(), timeout))
    except (asyncio.TimeoutError, TimeoutError):
        raise SweepError(f"--dask {address}: no Dask scheduler answered within {timeout:g} s (is it one? "
                         f"start it with dask scheduler, or use --dask local)") from None
    except Exception as exc:  # refused, unknown host, a handshake that failed, ...
        why = str(exc) if isinstance(exc, OSError) and str(exc) else f"{type(exc).__name__}: {exc}"
        raise SweepError(f"--dask {address}: cannot reach the Dask scheduler ({why}); "
                         f"start it (dask scheduler) or use --dask local") from None


def _run_dask(todo, sweep, out, workers, address, on_done, on_warm):
    from dask.distributed import Client, LocalCluster, as_completed

    cluster = None
    if address == "local":
        cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                               dashboard_address=None, silence_logs=50)
        client = Client(cluster)
    else:
        _reach_scheduler(address)
        try:
            client = Client(address, timeout=f"{DASK_CONNECT_TIMEOUT_S:g}s")
        except (OSError, TimeoutError, ValueError) as exc:  # not a write failure: name the scheduler
            raise SweepError(f"--dask {address}: cannot reach the Dask scheduler ({exc}); start it "
                             f"(dask scheduler) or use --dask local") from None
    try:
        for t in _warm_tasks(todo, sweep):
            on_warm(client.submit(warm_cache, t, pure=False).result())
        futs = {}
        for r in todo:
            f = client.submit(run_one, _task(r, sweep), key=f"clothsim-{r.run_id}-{os.getpid()}-{time.time_ns()}",
                              pure=False)
            futs[f.key] = (f, r)
        for f in as_completed([f for f, _ in futs.values()]):
            run = futs[f.key][1]
            try:
                payload = f.result()
            except Exception as exc:  # KilledWorker, lost connection, ...
                write_crashed(out, run, f"{type(exc).__name__}: {exc}; rerun to retry")
                on_done(run, {"status": "crashed"})
                f.release()
                continue
            f.release()
            write_run(out, payload)
            on_done(run, payload)
    finally:
        try:
            client.close()
        finally:
            if cluster is not None:
                cluster.close()
