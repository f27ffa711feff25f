"""The one execution layer of ``ehss train --seeds``, ``ehss evaluate``, ``ehss reproduce`` and ``ehss tune``.

A :class:`Job` is a pure function of (config, seed): ``fn(config, seed, context) -> result``, where ``fn`` is a
module-level function (importable on every node), ``config`` and ``seed`` say everything the result depends on,
and ``context`` is data shared by the jobs of one call (e.g. the policies an evaluation scores), sent once per
worker. The result is **plain data** (dicts, lists, tuples, str, int, float, bool, None, bytes, NumPy arrays and
scalars; no pickled objects), encoded as JSON by :func:`dumps` in the worker and decoded by :func:`loads` where it is
used, on every backend (so both backends hand back the very same values).

With a :class:`Store`, each result is written atomically to its own content-addressed folder
(``<root>/<key[:2]>/<key>/result.json``, the key a SHA-256 of the function, config, seed and the package's
source, :func:`job_key`) and a job whose folder is complete is skipped: an interrupted sweep, restarted,
recomputes only its missing jobs.

Backends (:class:`Backend`):

- ``local`` (the default; no Ray needed): the jobs in this process (one worker) or in ``spawn`` worker
  processes on this machine, as the commands did before.
- ``ray``: one Ray task per job, on the cluster at ``address`` (or ``RAY_ADDRESS``), or on a local Ray instance
  bound to 127.0.0.1 when there is none. Ray is an optional extra (``pip install 'ehss-gym[ray]'``).

The pitfalls handled here rather than by the callers: one torch/OpenMP and one numba thread per job unless
``threads`` says otherwise (jobs share the cores); MKL's code path pinned (:data:`BLAS_ENV`: a learned policy's
results do not depend on the machine's CPU); numba's cache in a node-local folder on Ray workers
(:data:`NUMBA_CACHE_ENV`: numba's cache is not safe to share between machines over a shared file system); the
seed passed to every job explicitly; Ray tasks retried when their worker dies (``max_retries``); results as
plain data, model weights as safe-weights files (the jobs that train return their bytes, see
:mod:`ehss_gym.train.jobs`).
"""

from __future__ import annotations

import base64
import dataclasses
import functools
import hashlib
import importlib
import importlib.util
import json
import math
import multiprocessing as mp
import os
import pathlib
import shutil
import socket
import sys
import tempfile
from collections.abc import Callable, Sequence
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from dataclasses import dataclass

import numpy as np
from tqdm import tqdm

from . import BACKENDS, DEFAULT_STORE, RAY_INSTALL

# every thread pool a job might start: torch/OpenMP, MKL, OpenBLAS and numba
THREAD_VARS = ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS", "NUMBA_NUM_THREADS")
NUMBA_CACHE_ENV = "NUMBA_CACHE_DIR"
# MKL (torch's BLAS on x86) picks its kernels by CPU: an AVX-512 machine sums a layer's products in another order than
# an AVX2 one, so a learned policy's actions, and the episodes they steer, differ in their last bits from machine to
# machine. Its conditional-numerical-reproducibility mode pins one code path: AVX2's, which every x86 CPU of the last
# decade runs (Intel and AMD alike). Its strict form also makes a row's result independent of its place in the batch
# (without it, identical observations in one batch got actions differing in the last bit). MKL reads it at its first
# call, so it is set before torch computes anything.
BLAS_ENV = {"MKL_CBWR": "AVX2,STRICT"}
RESULT = "result.json"
CONNECT_TIMEOUT = 3.0  # [s] to reach a Ray cluster's address before saying it is unreachable


class ExecutionError(ValueError):
    """Bad execution settings (unknown backend, Ray missing, unreachable address); the commands exit with 2."""


@dataclass(frozen=True)
class Job:
    """One unit of work: ``fn(config, seed, context)``.

    Attributes:
        fn: a module-level function returning plain data (see the module docstring).
        config: everything besides the seed that the result depends on (plain data or dataclasses of it).
        seed: the job's seed, passed explicitly.
        label: a short name for progress and error messages.
    """

    fn: Callable
    config: object
    seed: int = 0
    label: str = ""

    @property
    def name(self) -> str:
        """``module:function`` of :attr:`fn`."""
        return f"{self.fn.__module__}:{self.fn.__qualname__}"


# --- content addresses -------------------------------------------------------------------------------------


def canonical(obj):
    """A JSON-able form of ``obj`` that two equal inputs share (for hashing, not for decoding).

    Dicts are sorted by key, dataclasses and named tuples become their fields with the type name, floats their
    ``repr`` (so NaN and infinities hash), NumPy arrays their dtype, shape and a SHA-256 of their bytes, bytes a
    SHA-256, functions ``module.qualname``; other objects their type name and ``__dict__``.
    """
    if obj is None or isinstance(obj, (bool, int, str)):
        return obj
    if isinstance(obj, float):
        return repr(obj)
    if isinstance(obj, np.generic):
        return [str(obj.dtype), canonical(obj.item())]
    if isinstance(obj, np.ndarray):
        return ["ndarray", str(obj.dtype), list(obj.shape), hashlib.sha256(np.ascontiguousarray(obj)).hexdigest()]
    if isinstance(obj, (bytes, bytearray)):
        return ["bytes", hashlib.sha256(obj).hexdigest()]
    if isinstance(obj, dict):
        return ["dict", sorted((json.dumps(canonical(k)), canonical(v)) for k, v in obj.items())]
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return [type(obj).__qualname__, {f.name: canonical(getattr(obj, f.name)) for f in dataclasses.fields(obj)}]
    if isinstance(obj, tuple) and hasattr(obj, "_fields"):
        return [type(obj).__qualname__, {k: canonical(v) for k, v in zip(obj._fields, obj)}]
    if isinstance(obj, (list, tuple)):
        return [canonical(v) for v in obj]
    if isinstance(obj, (set, frozenset)):
        return ["set", sorted(json.dumps(canonical(v)) for v in obj)]
    if callable(obj) and hasattr(obj, "__qualname__"):
        return ["callable", f"{obj.__module__}.{obj.__qualname__}"]
    if hasattr(obj, "__dict__"):
        return [type(obj).__qualname__, canonical(vars(obj))]
    raise TypeError(f"cannot derive a content address from a {type(obj).__name__}")


@functools.cache
def code_fingerprint() -> str:
    """SHA-256 of the package's Python source (ehss_gym with its agents and train packages): a result computed
    by other code has another address, so an edit never serves a stale result."""
    h = hashlib.sha256()
    # the packages' folders, found without importing them (ehss_gym.train would load torch)
    roots = {pathlib.Path(loc) for m in ("ehss_gym", "ehss_gym.agents", "ehss_gym.train")
             for loc in importlib.util.find_spec(m).submodule_search_locations}
    for root in sorted(roots):
        for path in sorted(root.rglob("*.py")):
            h.update(path.relative_to(root).as_posix().encode())
            h.update(path.read_bytes())
    return h.hexdigest()


def job_key(job: Job) -> str:
    """The content address of ``job``: SHA-256 of its function, config, seed and :func:`code_fingerprint`."""
    blob = json.dumps([job.name, canonical(job.config), int(job.seed), code_fingerprint()], sort_keys=True,
                      separators=(",", ":"))
    return hashlib.sha256(blob.encode()).hexdigest()


# --- plain data --------------------------------------------------------------------------------------------


def encode(obj):
    """``obj`` as JSON-able data that :func:`decode` turns back into an equal object (tuples stay tuples, NumPy
    arrays and scalars keep their dtype, floats their bits).

    Raises:
        TypeError: ``obj`` holds something that is not plain data (a model, a Python object, ...).
    """
    if obj is None or isinstance(obj, (bool, str)):
        return obj
    if isinstance(obj, np.generic):
        return {"__np__": str(obj.dtype), "v": encode(obj.item())}
    if isinstance(obj, int):
        return obj
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else {"__float__": repr(obj)}
    if isinstance(obj, np.ndarray):
        if obj.dtype.hasobject:
            raise TypeError("a result may not hold object arrays")
        data = base64.b64encode(np.ascontiguousarray(obj).tobytes()).decode()
        return {"__ndarray__": obj.dtype.str, "shape": list(obj.shape), "data": data}
    if isinstance(obj, (bytes, bytearray)):  # file contents, e.g. safe weights
        return {"__bytes__": base64.b64encode(obj).decode()}
    if isinstance(obj, tuple):
        return {"__tuple__": [encode(v) for v in obj]}
    if isinstance(obj, list):
        return [encode(v) for v in obj]
    if isinstance(obj, dict):
        if all(isinstance(k, str) for k in obj) and not any(k.startswith("__") for k in obj):
            return {k: encode(v) for k, v in obj.items()}
        return {"__items__": [[encode(k), encode(v)] for k, v in obj.items()]}
    raise TypeError(f"a job result must be plain data (dict, list, tuple, str, int, float, bool, None, bytes, "
                    f"NumPy arrays); got a {type(obj).__module__}.{type(obj).__qualname__}")


def decode(obj):
    """The inverse of :func:`encode`."""
    if isinstance(obj, list):
        return [decode(v) for v in obj]
    if not isinstance(obj, dict):
        return obj
    if "__np__" in obj:
        return np.dtype(obj["__np__"]).type(decode(obj["v"]))
    if "__float__" in obj:
        return float(obj["__float__"])
    if "__ndarray__" in obj:
        raw = base64.b64decode(obj["data"])
        return np.frombuffer(raw, dtype=np.dtype(obj["__ndarray__"])).reshape(obj["shape"]).copy()
    if "__tuple__" in obj:
        return tuple(decode(v) for v in obj["__tuple__"])
    if "__bytes__" in obj:
        return base64.b64decode(obj["__bytes__"])
    if "__items__" in obj:
        return {decode(k): decode(v) for k, v in obj["__items__"]}
    return {k: decode(v) for k, v in obj.items()}


def dumps(result) -> str:
    """``result`` as JSON text (:func:`encode`); TypeError if it is not plain data."""
    return json.dumps(encode(result), separators=(",", ":"))


def loads(text: str):
    """The result of :func:`dumps` text."""
    return decode(json.loads(text))


# --- the store -------------------------------------------------------------------------------------------------


class Store:
    """Content-addressed results: ``<root>/<key[:2]>/<key>/`` holding ``result.json`` and ``job.json``.

    A folder is written under a temporary name (``.tmp-...``, its files flushed to disk), then renamed into place,
    so it is either complete or absent: a killed run leaves no half result, and a complete one is never computed
    again. Readers look only at folders named by a key, never at a temporary one, whatever it holds.
    """

    def __init__(self, root: str):
        """Results under ``root`` (created on the first write)."""
        self.root = str(root)

    def folder(self, key: str) -> str:
        """The folder of the result with address ``key``."""
        return os.path.join(self.root, key[:2], key)

    def load(self, key: str) -> str | None:
        """The stored result text of ``key``, or None when there is none."""
        if not is_key(key):
            return None
        try:
            with open(os.path.join(self.folder(key), RESULT), encoding="utf-8") as f:
                return f.read()
        except FileNotFoundError:
            return None

    def save(self, key: str, job: Job, text: str) -> None:
        """Write the result text of ``job`` (address ``key``) atomically; a result already there is kept."""
        final = self.folder(key)
        if os.path.isdir(final):
            return
        parent = os.path.dirname(final)
        os.makedirs(parent, exist_ok=True)
        tmp = tempfile.mkdtemp(dir=parent, prefix=f"{TMP_PREFIX}{key[:8]}-")
        try:
            _write_synced(os.path.join(tmp, "job.json"),
                          json.dumps({"fn": job.name, "label": job.label, "seed": int(job.seed), "key": key}))
            _write_synced(os.path.join(tmp, RESULT), text)
            _fsync_dir(tmp)
            os.replace(tmp, final)
        except OSError:
            # another process completed the same job first (the rename found a folder): its result stands
            shutil.rmtree(tmp, ignore_errors=True)
            if not os.path.isdir(final):
                raise
        else:
            _fsync_dir(parent)  # the rename itself survives a crash

    def keys(self) -> list[str]:
        """The addresses of the complete results (never a folder still being written, nor one a killed writer
        left under its temporary name)."""
        if not os.path.isdir(self.root):
            return []
        return sorted(k for d in os.listdir(self.root) if len(d) == 2 and os.path.isdir(os.path.join(self.root, d))
                      for k in os.listdir(os.path.join(self.root, d))
                      if is_key(k) and k.startswith(d) and os.path.isfile(os.path.join(self.root, d, k, RESULT)))


TMP_PREFIX = ".tmp-"
_HEX = frozenset("0123456789abcdef")


def is_key(name: str) -> bool:
    """Whether ``name`` is a content address (64 lower-case hex digits, :func:`job_key`)."""
    return len(name) == 64 and _HEX.issuperset(name)


def _write_synced(path: str, text: str) -> None:
    """Write ``text`` to ``path`` and flush it to the disk (a rename after it never publishes a short file)."""
    with open(path, "w", encoding="utf-8") as f:
        f.write(text)
        f.flush()
        os.fsync(f.fileno())


def _fsync_dir(path: str) -> None:
    """Flush a folder's entries to the disk (where the platform lets a folder be opened)."""
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:  # Windows opens no folders; its rename is durable enough for a cache
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


# --- backends --------------------------------------------------------------------------------------------------


def usable_cores() -> int:
    """CPU cores this process may run on."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not on Linux
        return max(1, os.cpu_count() or 1)


def require_ray():
    """The ``ray`` module, or ExecutionError saying how to install it."""
    try:
        return importlib.import_module("ray")  # optional: only the ray backend needs it
    except ImportError:
        raise ExecutionError(f"--backend ray needs Ray, which is not installed; install it with: {RAY_INSTALL}") \
            from None


def check_address(address: str) -> None:
    """ExecutionError unless a Ray cluster's ``host:port`` (or ``ray://host:port``) answers within
    :data:`CONNECT_TIMEOUT` (ray.init would otherwise wait a minute and print a traceback); ``auto`` is left to
    Ray."""
    if address == "auto":
        return
    hostport = address.split("://", 1)[-1]
    host, sep, port = hostport.rpartition(":")
    if not sep or not host or not port.isdigit():
        raise ExecutionError(f"--address must be HOST:PORT (e.g. 127.0.0.1:6379), ray://HOST:PORT or auto, "
                             f"got {address!r}")
    try:
        with socket.create_connection((host, int(port)), timeout=CONNECT_TIMEOUT):
            pass
    except OSError as exc:
        raise ExecutionError(f"--address {address}: no Ray cluster reachable there ({exc.strerror or exc}); start "
                             f"one with 'ray start --head' or fix the address") from None


@dataclass(frozen=True)
class Backend:
    """Where jobs run.

    Attributes:
        name: ``local`` or ``ray``.
        address: the Ray cluster to join (``ray`` only; None: ``RAY_ADDRESS``, else a local Ray instance).
        workers: parallel jobs (local: worker processes, default the usable cores; ray on a local instance:
            its CPUs; on a cluster: ignored, the cluster's CPUs decide).
        threads: torch/OpenMP and numba threads per job (1: the jobs share the cores).
        max_retries: times a Ray task is retried after its worker process or node died.
    """

    name: str = "local"
    address: str | None = None
    workers: int | None = None
    threads: int = 1
    max_retries: int = 3

    def validate(self) -> Backend:
        """ExecutionError for an unknown backend, a bad count, or ray asked for without Ray installed."""
        if self.name not in BACKENDS:
            raise ExecutionError(f"--backend must be one of {', '.join(BACKENDS)}, got {self.name!r}")
        for field, low in (("workers", 1), ("threads", 1), ("max_retries", 0)):
            v = getattr(self, field)
            if v is not None and (isinstance(v, bool) or not isinstance(v, int) or v < low):
                raise ExecutionError(f"--{field.replace('_', '-')} must be an integer >= {low}, got {v!r}")
        if self.address is not None and self.name != "ray":
            raise ExecutionError("--address joins a Ray cluster: it needs --backend ray")
        if self.name == "ray":
            require_ray()
        return self

    def ray_address(self) -> str | None:
        """The cluster address to join: ``address``, else ``RAY_ADDRESS``, else None (a local instance)."""
        return self.address or os.environ.get("RAY_ADDRESS") or None



def thread_env(threads: int) -> dict:
    """The environment variables that cap a job's thread pools at ``threads``."""
    return {v: str(threads) for v in THREAD_VARS}


def pin_blas() -> dict:
    """Pin MKL's code path (:data:`BLAS_ENV`) in this process's environment, and so in the processes it starts,
    unless the user set the variable; effective when called before the process's first torch computation.

    Returns:
        The pinned variables as set (what a Ray worker's runtime environment gets).
    """
    for key, value in BLAS_ENV.items():
        os.environ.setdefault(key, value)
    return {key: os.environ[key] for key in BLAS_ENV}


def numba_cache_dir() -> str:
    """A numba cache folder on the local disk of whichever node reads the variable (``/tmp`` is per node), one per
    version of the package's source (:func:`code_fingerprint`).

    Per version because numba revalidates a cached kernel against its own file only: after an edit of a module
    whose constants it compiled in (the buffer indices of ``core/layout.py``), a shared folder would hand the
    workers stale machine code that indexes the new buffers with the old offsets (a heap corruption, not an error).
    """
    user = os.environ.get("USER") or (str(os.getuid()) if hasattr(os, "getuid") else "user")
    return os.path.join(tempfile.gettempdir(), f"ehss-gym-numba-{user}-{code_fingerprint()[:12]}")


def set_threads(threads: int) -> None:
    """Cap this process's numba and (if loaded) torch threads at ``threads``; environment variables for the
    libraries that load later."""
    numba = sys.modules.get("numba")
    # numba re-reads NUMBA_NUM_THREADS while compiling and refuses a change once its pool runs: once loaded, it
    # is capped through its API only
    os.environ.update({k: v for k, v in thread_env(threads).items()
                       if not (numba is not None and k == "NUMBA_NUM_THREADS")})
    if numba is not None:
        numba.set_num_threads(max(1, min(threads, numba.config.NUMBA_NUM_THREADS)))
    torch = sys.modules.get("torch")
    if torch is not None:
        torch.set_num_threads(threads)


# --- running a job (in whatever process it lands) --------------------------------------------------------------

_CONTEXT: dict = {}  # a local worker process's context, set once by its initializer


def _worker_init(context, threads: int) -> None:
    """A local worker process: its context (sent once, when the pool starts) and its thread caps."""
    _CONTEXT["value"] = context
    set_threads(threads)


def run_one(job: Job, context, threads: int | None) -> str:
    """Run ``job`` here and return its result as JSON text (:func:`dumps`); ``threads`` None leaves the thread
    pools as they are (the local in-process case, as before)."""
    if threads is not None:
        set_threads(threads)
    return dumps(job.fn(job.config, job.seed, context))


def _run_in_worker(job: Job, threads: int) -> str:
    return run_one(job, _CONTEXT.get("value"), threads)


def _ray_task(job: Job, context, threads: int) -> str:
    # a Ray worker: numba's cache and thread caps come from the job's runtime_env (set before numba loads)
    return run_one(job, context, threads)


# --- the executor ----------------------------------------------------------------------------------------------


class Executor:
    """Runs lists of jobs on a backend, through a store when given; a context manager (leaving it disconnects
    from Ray, and stops a local Ray instance it started).

    Attributes:
        computed: jobs run so far.
        skipped: jobs served from the store.
    """

    def __init__(self, backend: Backend | None = None, store: Store | str | None = None, progress: bool = False):
        """Run on ``backend`` (default local), keep results in ``store`` (a Store or its root; None: keep none).

        Raises:
            ExecutionError: bad backend settings, or a Ray cluster's address that does not answer (checked here, so
                a command asked to reach a cluster says so even when the store holds every result it needs).
        """
        pin_blas()  # before any job computes here or in a worker process started from here
        self.backend = (backend or Backend()).validate()
        if self.backend.name == "ray" and self.backend.ray_address() is not None:
            check_address(self.backend.ray_address())
        self.store = Store(store) if isinstance(store, (str, os.PathLike)) else store
        self.progress = progress
        self.computed = 0
        self.skipped = 0
        self._ray = None
        self._started_ray = False

    # -- connection ---------------------------------------------------------------------------------------------

    def __enter__(self) -> Executor:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        """Disconnect from Ray (stopping a local instance this executor started)."""
        if self._ray is not None and self._started_ray:
            self._ray.shutdown()
        self._ray = None

    def ray(self):
        """The connected ``ray`` module (connecting on first use; see :class:`Backend`)."""
        if self._ray is not None:
            return self._ray
        ray = require_ray()
        address = self.backend.ray_address()
        if address is not None:
            check_address(address)
        if ray.is_initialized():  # the caller's own Ray session (a script, a test): used, and left running
            self._ray = ray
            return ray
        env = {**thread_env(self.backend.threads), NUMBA_CACHE_ENV: numba_cache_dir(), **pin_blas()}
        runtime_env = {"env_vars": env}
        if address is not None:
            try:
                ray.init(address=address, runtime_env=runtime_env, log_to_driver=False, ignore_reinit_error=True)
            except (ConnectionError, RuntimeError) as exc:  # reachable, but Ray refused (e.g. its token check)
                cause = f" ({exc.__cause__})" if exc.__cause__ else ""
                raise ExecutionError(f"--address {address}: cannot join the Ray cluster: {exc}{cause}; a cluster "
                                     "started with ray start checks a token: set RAY_AUTH_MODE=token here too "
                                     "(docs/RAY.md)") from None
        else:
            # address "local": a new instance of our own, never a cluster some other process left running here
            ray.init(address="local", num_cpus=self.backend.workers or usable_cores(), include_dashboard=False,
                     _node_ip_address="127.0.0.1", runtime_env=runtime_env, log_to_driver=False,
                     ignore_reinit_error=True)
        self._ray, self._started_ray = ray, True
        return ray

    def workers(self) -> int:
        """Parallel jobs the backend runs (Ray: the CPUs of the cluster divided by the threads per job)."""
        if self.backend.name == "ray":
            return max(1, int(self.ray().cluster_resources().get("CPU", 1)) // self.backend.threads)
        return self.backend.workers or usable_cores()

    # -- running ------------------------------------------------------------------------------------------------

    def map(self, jobs: Sequence[Job], context=None, desc: str = "jobs", fresh_process: bool = False,
            in_process: bool | None = None) -> list:
        """The results of ``jobs``, in their order (each decoded from its plain-data form).

        Args:
            jobs: the jobs.
            context: data every job gets as its third argument (sent once per worker, or put in Ray's object
                store once); it must not change a result without its job's config changing too.
            desc: the progress bar's label.
            fresh_process: local backend: a new worker process per job (training: a clean torch state).
            in_process: run the jobs in this process whatever the backend (default: on the local backend with one
                worker and no fresh process asked for), leaving its thread pools as they are.

        Raises:
            RuntimeError: a job failed (the message names it and the failure); results finished before it are in
                the store.
        """
        keys = [job_key(j) for j in jobs] if self.store is not None else [None] * len(jobs)
        texts: dict[int, str] = {}
        todo = []
        for i, key in enumerate(keys):
            text = self.store.load(key) if key is not None else None
            if text is None:
                todo.append(i)
            else:
                texts[i] = text
        self.skipped += len(jobs) - len(todo)
        bar = tqdm(total=len(jobs), initial=len(jobs) - len(todo), desc=desc, unit="job", disable=not self.progress,
                   file=sys.stderr)
        try:
            for i, text in self._run(jobs, todo, context, fresh_process, in_process):
                if keys[i] is not None:
                    self.store.save(keys[i], jobs[i], text)
                texts[i] = text
                self.computed += 1
                bar.update(1)
        finally:
            bar.close()
        return [loads(texts[i]) for i in range(len(jobs))]

    def _run(self, jobs, todo, context, fresh_process, in_process):
        """(index, result text) of the jobs ``todo``, as they finish."""
        if not todo:
            return
        if self.backend.name == "ray" and not in_process:
            yield from self._run_ray(jobs, todo, context)
            return
        workers = min(self.backend.workers or usable_cores(), len(todo))
        if in_process if in_process is not None else (workers == 1 and not fresh_process):
            for i in todo:
                yield i, _checked(jobs[i], lambda job=jobs[i]: run_one(job, context, None))
            return
        yield from self._run_pool(jobs, todo, context, workers, fresh_process)

    def _run_pool(self, jobs, todo, context, workers, fresh_process):
        """Local worker processes (spawn: no state inherited from this process), longest-first order kept."""
        pool = ProcessPoolExecutor(workers, mp_context=mp.get_context("spawn"), initializer=_worker_init,
                                   initargs=(context, self.backend.threads),
                                   max_tasks_per_child=1 if fresh_process else None)
        try:
            futures = {pool.submit(_run_in_worker, jobs[i], self.backend.threads): i for i in todo}
            pending = set(futures)
            while pending:
                done, pending = wait(pending, return_when=FIRST_COMPLETED)
                for fut in done:
                    i = futures[fut]
                    yield i, _checked(jobs[i], fut.result)
        finally:
            pool.shutdown(wait=True, cancel_futures=True)

    def _run_ray(self, jobs, todo, context):
        """One Ray task per job (retried when its worker dies), gathered as they finish."""
        ray = self.ray()
        remote = ray.remote(_ray_task).options(num_cpus=self.backend.threads, max_retries=self.backend.max_retries,
                                               retry_exceptions=False)
        ctx = ray.put(context)
        refs = {remote.remote(jobs[i], ctx, self.backend.threads): i for i in todo}
        pending = list(refs)
        try:
            while pending:
                done, pending = ray.wait(pending, num_returns=1)
                for ref in done:
                    i = refs[ref]
                    yield i, _checked(jobs[i], lambda ref=ref: ray.get(ref))
        finally:
            for ref in pending:  # an interrupted map leaves no task of ours running on the cluster
                ray.cancel(ref, force=True)


def _checked(job: Job, get: Callable[[], str]) -> str:
    """``get()``, with a failure re-raised as RuntimeError naming the job."""
    try:
        return get()
    except Exception as exc:
        what = job.label or job.name
        cause = getattr(exc, "cause", None) or exc  # Ray wraps the job's exception in a RayTaskError
        raise RuntimeError(f"job {what} (seed {job.seed}) failed: {type(cause).__name__}: {cause}") from exc


__all__ = ["BACKENDS", "RAY_INSTALL", "DEFAULT_STORE", "ExecutionError", "Job", "Store", "Backend", "Executor",
           "canonical", "code_fingerprint", "job_key", "encode", "decode", "dumps", "loads", "usable_cores",
           "require_ray", "check_address", "thread_env", "pin_blas", "BLAS_ENV", "numba_cache_dir", "set_threads",
           "run_one"]
