"""Batched experiments sharded over every device of every process, on JAX's own runtime.

A batch of designs (radii, tilts, control nets, …) is the leading axis of pytree arguments.
`map(fn, *args)` is `jax.vmap(fn)(*args)` with the batch split over a 1-D device mesh named
`"batch"` (`jax.sharding.Mesh` over `jax.devices()`, `NamedSharding(mesh, PartitionSpec("batch"))`),
so each device evaluates its own block of designs; with `jax.distributed` (`initialize`) the mesh
spans the devices of every process and each process contributes only its own shards. `gather`
brings a result to the host, from every process. Nothing here is a home-made cluster: the
devices, the collectives and the process group are JAX's.

- `map(fn, *args, mesh=None, chunk=None, progress=None)` — sharded `vmap` with padding, chunks
  and a progress callback.
- `gather(tree)` — every leaf as a numpy array holding the whole (global) batch.
- `initialize(coordinator=None, num_processes=None, process_id=None)` — `jax.distributed`
  from arguments, `BSJAX_*` environment variables or JAX's cluster auto-detection.
- `mesh(devices=None)` — the 1-D `"batch"` mesh.
- `report_progress(progress, done, total)` — call a `progress(done, total)` callback from inside
  compiled code (the progress of long rollouts, trainings and refits).

Source: scale-out through JAX's own runtime; the sharding model is JAX's
(*Distributed arrays and automatic parallelization*, *Multi-process environments* in the JAX
documentation).
"""

from __future__ import annotations

import collections
import functools
import inspect
import os
from collections.abc import Callable, Sequence
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec

from bsjax import _boundary, _checks
from bsjax._declared import declared

__all__ = ["gather", "initialize", "map", "mesh", "report_progress"]

AXIS = "batch"
_CACHE_SIZE = 64


# --- the mesh --------------------------------------------------------------------------------
def mesh(devices: Sequence[Any] | None = None) -> Mesh:
    """The 1-D device mesh with one axis named `"batch"`.

    **Arguments:**
    - `devices`: the devices to shard over, in order; default `jax.devices()` — every device of
      every process (after `initialize`, the global device list).

    **Returns:** `jax.sharding.Mesh(devices, ("batch",))`.
    """
    if devices is None:
        return _default_mesh(tuple(jax.devices()))
    devices = list(devices)
    if not devices or not all(isinstance(d, jax.Device) for d in devices):
        kinds = sorted({type(d).__name__ for d in devices}) or "an empty list"
        raise TypeError(f"devices: expected a non-empty sequence of jax devices, got {kinds}")
    return Mesh(np.asarray(devices, dtype=object), (AXIS,))


@_boundary.host_cache(maxsize=8)
def _default_mesh(devices: tuple) -> Mesh:
    return Mesh(np.asarray(devices, dtype=object), (AXIS,))


def _checked_mesh(value) -> Mesh:
    if value is None:
        return mesh()
    if not isinstance(value, Mesh):
        raise TypeError(
            f"mesh: expected a jax.sharding.Mesh (see bsjax.batch.mesh), got {type(value).__name__}"
        )
    return value


def _batch_spec(grid: Mesh) -> PartitionSpec:
    """Leading axis split over every axis of `grid` (the one `"batch"` axis of `mesh()`)."""
    return PartitionSpec(tuple(grid.axis_names))


@_boundary.host_cache(maxsize=8)
def _shardings(grid: Mesh) -> tuple[NamedSharding, NamedSharding]:
    """The batch sharding and the replicated one of `grid`."""
    return NamedSharding(grid, _batch_spec(grid)), NamedSharding(grid, PartitionSpec())


# --- the compiled, vmapped function, cached per (fn, mesh) --------------------------------------
def _split(fn: Callable) -> tuple[Callable, tuple, dict]:
    """`(core, args, kwargs)` with `fn(*items) == core(*args, *items, **kwargs)`: a
    `functools.partial`, a bound method (`blending.points`) or a callable `eqx.Module` is its
    function and its bound values, so that a new such object over new arrays of the same shapes
    reuses one compilation."""
    if isinstance(fn, functools.partial):
        core, args, kwargs = _split(fn.func)
        return core, (*args, *fn.args), {**kwargs, **fn.keywords}
    owner, func = getattr(fn, "__self__", None), getattr(fn, "__func__", None)
    if owner is not None and callable(func) and not inspect.ismodule(owner):
        return func, (owner,), {}
    if isinstance(fn, eqx.Module):  # a callable module: its arrays are its bound values
        return _call, (fn,), {}
    return fn, (), {}


def _call(module, *items):
    return module(*items)


_UNBOUND = jax.tree.structure(((), {}))


class _MappedCache:
    """`jax.jit` of the sharded `jax.vmap(fn)` per `(fn, mesh)`, least recently used dropped
    past 64 entries; `jax.jit` itself keeps one executable per argument structure and shapes.

    A `functools.partial` or bound method is keyed by its function and the structure and static
    leaves of its bound values; their arrays are passed as (replicated) arguments. Registered
    with `bsjax.clear_caches()`.
    """

    def __init__(self, size: int):
        self._size = size
        self._entries: collections.OrderedDict = collections.OrderedDict()

    def get(self, fn: Callable, grid: Mesh) -> tuple[Callable, list]:
        """The compiled function `run(bound_arrays, *batched)` and `fn`'s bound arrays."""
        core, args, kwargs = _split(fn)
        leaves, treedef = jax.tree_util.tree_flatten((args, kwargs))
        mask = tuple(_boundary.is_traced(leaf) for leaf in leaves)
        static = tuple(None if m else leaf for m, leaf in zip(mask, leaves))
        dynamic = [leaf for m, leaf in zip(mask, leaves) if m]
        key = (core, treedef, mask, static, grid)
        try:
            jitted = self._entries.get(key)
        except TypeError:  # an unhashable static bound value: compiled for this call alone
            return jax.jit(_sharded_vmap(fn, _UNBOUND, (), (), grid)), []
        if jitted is None:
            jitted = jax.jit(_sharded_vmap(core, treedef, mask, static, grid))
            self._entries[key] = jitted
            if len(self._entries) > self._size:
                self._entries.popitem(last=False)
        else:
            self._entries.move_to_end(key)
        return jitted, dynamic

    def clear_cache(self) -> None:
        self._entries.clear()


def _sharded_vmap(core: Callable, treedef, mask: tuple, static: tuple, grid: Mesh) -> Callable:
    """`jax.vmap` of `core(*bound, *items)` run by `jax.shard_map` on each device's own block
    of the batch, the bound arrays replicated.

    Each device runs its block alone, with no collective between devices: a value check of `fn`
    (`eqx.error_if`) that fails on one device then fails the call instead of leaving the others
    waiting in a cross-device reduction, as the automatic partitioning of `jit` would.
    """
    spec = _batch_spec(grid)

    def one(dynamic, *items):
        it = iter(dynamic)
        leaves = [next(it) if m else s for m, s in zip(mask, static)]
        args, kwargs = jax.tree_util.tree_unflatten(treedef, leaves)
        return core(*args, *items, **kwargs)

    def run(dynamic, *batched):
        size = jax.tree.leaves(batched)[0].shape[0]
        padded = jax.tree.map(lambda x: _pad(x, 0, size, -(-size // grid.size) * grid.size), batched)
        block = jax.vmap(one, in_axes=(None,) + (0,) * len(batched))
        specs = (PartitionSpec(),) + (spec,) * len(batched)
        out = jax.shard_map(block, mesh=grid, in_specs=specs, out_specs=spec, check_vma=False)(
            dynamic, *padded
        )
        layout = NamedSharding(grid, spec if size % grid.size == 0 else PartitionSpec())
        return jax.tree.map(lambda x: jax.lax.with_sharding_constraint(x[:size], layout), out)

    return run


_mapped = _MappedCache(_CACHE_SIZE)
_boundary.register(_mapped)


# --- the arguments ---------------------------------------------------------------------------
def _batch_size(args: tuple) -> int:
    """The common leading size of every leaf of `args` (structure errors name the leaf)."""
    leaves, _ = jax.tree_util.tree_flatten_with_path(args)
    if not leaves:
        _checks.fail("args", "at least one array with a leading batch axis", "no array leaves")
    size, first = None, None
    for path, leaf in leaves:
        name = "args" + jax.tree_util.keystr(path)
        shape = _leaf_shape(leaf, name)
        if size is None:
            size, first = shape[0], name
            if size == 0:
                _checks.fail(name, "a non-empty batch (leading size >= 1)", f"shape {shape}")
        elif shape[0] != size:
            _checks.fail(name, f"leading (batch) size {size}, as {first}", f"shape {shape}")
    assert size is not None
    return size


def _leaf_shape(leaf, name: str) -> tuple[int, ...]:
    if isinstance(leaf, (jax.Array, np.ndarray, _checks._Tracer)):
        shape = tuple(leaf.shape)
    else:
        kind = np.asarray(leaf).dtype.kind
        if kind not in "biuf":
            raise TypeError(f"{name}: expected an array with a leading batch axis, got {type(leaf).__name__}")
        shape = np.shape(leaf)
    if not shape:
        _checks.fail(name, "an array with a leading batch axis", f"a scalar {type(leaf).__name__}")
    return shape


def _pad(leaf, start: int, stop: int, size: int):
    """Items `start:stop` of `leaf`, the last one repeated up to `size` items."""
    if start == 0 and stop == size == leaf.shape[0]:
        return leaf
    if stop - start == size:
        return leaf[start:stop]
    return leaf[np.minimum(np.arange(start, start + size), stop - 1)]


def _place(leaf, start: int, stop: int, size: int, sharding: NamedSharding, several: bool):
    """`_pad` of a concrete `leaf` as a global array with `sharding`; with `several` processes,
    each transfers only its addressable shards."""
    if isinstance(leaf, jax.Array) and not leaf.is_fully_addressable:
        if start == 0 and stop == size == leaf.shape[0]:
            return leaf  # already a global array of the whole batch
        leaf = _allgather(leaf)
    part = _pad(leaf, start, stop, size)
    if not several:
        return jax.device_put(part, sharding)
    host = np.asarray(part)
    return jax.make_array_from_callback(host.shape, sharding, lambda index: host[index])


def _place_replicated(leaf, replicated: NamedSharding, several: bool):
    """A concrete bound value of `fn` as an argument of the mesh's computation: as it is in one
    process unless committed to other devices; a global replicated array with `several`."""
    if not several:
        committed = isinstance(leaf, jax.Array) and leaf.committed
        if committed and leaf.sharding.device_set != replicated.device_set:
            return jax.device_put(leaf, replicated)
        return leaf
    if isinstance(leaf, jax.Array) and not leaf.is_fully_addressable:
        return leaf
    host = np.asarray(leaf)
    return jax.make_array_from_callback(host.shape, replicated, lambda index: host[index])


@functools.partial(jax.jit, static_argnames=("n", "sharding"))
def _assemble(pieces: list, n: int, sharding: NamedSharding):
    """The chunks' results joined along the batch axis and cut to the `n` real items."""
    # Cut before joining: XLA's partitioner rejects a slice of a concatenation here.
    pieces = list(pieces)
    done = n - sum(jax.tree.leaves(p)[0].shape[0] for p in pieces[:-1])
    pieces[-1] = jax.tree.map(lambda x: x[:done], pieces[-1])
    out = pieces[0] if len(pieces) == 1 else jax.tree.map(lambda *xs: jnp.concatenate(xs), *pieces)
    return jax.tree.map(lambda x: jax.lax.with_sharding_constraint(x, sharding), out)


def _run(mapped: Callable, inputs: tuple, wait: bool):
    """`mapped(*inputs)`; in a direct call (`wait`) its results are awaited, so that a chunk
    holds its memory only while it runs and a failed `eqx.error_if` value check of `fn` raises
    here, as the `ValueError` the compiled public functions raise (`bsjax._boundary`)."""
    try:
        out = mapped(*inputs)
        return jax.block_until_ready(out) if wait else out
    except (jax.errors.JaxRuntimeError, ValueError) as err:
        failure = _boundary.check_failure(err)
        if failure is None:
            raise
        raise failure from None


# --- map -------------------------------------------------------------------------------------
@declared
def map(  # the name users expect, as `jax.lax.map`
    fn: Callable,
    *args: Any,
    mesh: Mesh | None = None,
    chunk: int | None = None,
    progress: Callable[[int, int], Any] | None = None,
) -> Any:
    """`jax.vmap(fn)(*args)`, sharded along the batch axis over every device of every process.

    **Arguments:**
    - `fn`: a function of one design (`fn(*items) -> pytree of arrays`), e.g.
      `functools.partial(collide.contacts, blending, ctrl)` of one tool. Values that are the same
      for every design are bound (`functools.partial`, a bound method) or closed over, not
      passed in `args`.
    - `*args`: pytrees whose every leaf is an array `(B, …)` with the same batch size `B ≥ 1`
      (a list of numbers counts as an array). In multi-process use every process passes the
      same global batch.
    - `mesh`: a `jax.sharding.Mesh`; default `mesh()` over `jax.devices()`. The batch axis is
      split over all its axes.
    - `chunk`: evaluate `chunk` items at a time (rounded up to a multiple of the device count),
      for batches whose inputs or intermediates do not fit in memory at once; the chunks'
      results are joined. Default: the whole batch at once.
    - `progress`: an optional callback `progress(done, total)` called after each chunk (the
      whole batch is one chunk when `chunk` is None) once its results are ready, with the
      numbers of designs done and in all. Not called inside a caller's trace.

    **Returns:** the pytree `jax.vmap(fn)(*args)`, each leaf `(B, …)`. The batch is padded to a
    multiple `D⌈B/D⌉` of the `D` devices by repeating its last design, and the padding dropped
    after. When `B` is a multiple of `D` each leaf stays sharded along the batch axis,
    `NamedSharding(mesh, PartitionSpec("batch"))`, device `i` holding designs
    `iB/D … (i+1)B/D − 1`; otherwise the (small) result is replicated on every device. `gather`
    brings it to the host.

    Compilation: `jax.jit` of `jax.shard_map(jax.vmap(fn))` is kept per `(fn, mesh)` and
    compiled once per argument structure, shapes and chunk size; a repeated direct call costs
    one dispatch and waits for its results (so that a failed value check of `fn`, an
    `eqx.error_if`, raises `ValueError` here and a chunk holds memory only while it runs). A
    `functools.partial`, a bound method (`blending.points`) or a callable `eqx.Module` is keyed
    by its function and static values, its arrays passed as replicated arguments: a new one over
    new arrays of the same shapes reuses the compilation. A fresh `lambda` per call compiles per
    call. Inside a caller's `jit`, `vmap` or `grad` the same function is traced into the
    caller's program (differentiable).
    """
    if not callable(fn):
        raise TypeError(f"fn: expected a callable (a function of one design), got {type(fn).__name__}")
    grid = _checked_mesh(mesh)
    _checks.check_progress(progress)
    args = _boundary.as_arrays(args, {})[0]
    n = _batch_size(args)
    devices = grid.size
    step = n if chunk is None else _checks.check_count(chunk, "chunk")
    step = -(-min(step, n) // devices) * devices  # ≥ n when one chunk holds the whole batch
    sharding, replicated = _shardings(grid)
    mapped, bound = _mapped.get(fn, grid)
    traced = not _checks.is_concrete((args, bound))
    several = jax.process_count() > 1
    if not traced:
        bound = [_place_replicated(leaf, replicated, several) for leaf in bound]
    if step >= n and (traced or not several):  # one call; `mapped` pads and cuts the batch
        out = _run(mapped, (bound, *args), wait=not traced)
        if progress is not None and not traced:
            progress(n, n)
        return out
    pieces = []
    for start in range(0, n, step):  # every chunk `step` items (one compilation), the last padded
        stop = min(start + step, n)
        if traced:
            inputs = jax.tree.map(lambda leaf: _pad(leaf, start, stop, step), args)
        else:
            inputs = jax.tree.map(lambda leaf: _place(leaf, start, stop, step, sharding, several), args)
        pieces.append(_run(mapped, (bound, *inputs), wait=not traced))
        if progress is not None and not traced:
            progress(stop, n)
    return _assemble(pieces, n, sharding if n % devices == 0 else replicated)


# --- progress from inside compiled code ------------------------------------------------------
@declared
def report_progress(
    progress: Callable[[int, int], Any] | None, done: int | None, total: int, after: Any = None
) -> None:
    """Call `progress(done, total)` on the host once the computation reaches this point.

    For the long computations of the library (`mss.simulate`, `vsofm.fit`, `merge.refit`): when
    `done` or `after` is traced it is `jax.debug.callback(..., ordered=True)`, so the calls come
    in program order, also under `vmap` (once, when `done` is not batched) and `grad`; when both
    are concrete it is a plain call. `progress=None` does nothing and adds nothing to the
    program: a function given no callback compiles to the same program as without the feature.

    **Arguments:**
    - `progress`: the callback, or None.
    - `done`: an int, or a traced integer scalar (a loop counter; None where `progress` is None);
      `total`: an int.
    - `after`: a pytree the report waits for (e.g. the loop's state), so that the call happens
      once that value is computed.
    """
    if progress is None:
        return
    leaves = jax.tree.leaves(after)
    token = jnp.ravel(leaves[0])[:1] if leaves else None
    if _checks.is_concrete((done, token)):
        progress(int(done), int(total))
        return
    jax.debug.callback(functools.partial(_call_progress, progress, int(total)), done, token, ordered=True)


def _call_progress(progress: Callable, total: int, done, token) -> None:
    del token  # only orders the call after the value it was taken from
    progress(int(done), total)


# --- gather ----------------------------------------------------------------------------------
def _allgather(leaf):
    from jax.experimental import multihost_utils

    return np.asarray(multihost_utils.process_allgather(leaf, tiled=True))


def gather(tree: Any) -> Any:
    """Every leaf of `tree` as a host numpy array holding the whole batch.

    **Arguments:**
    - `tree`: a pytree of arrays, e.g. the result of `map` — sharded over devices, or (after
      `initialize`) over the devices of several processes.

    **Returns:** the same pytree with numpy leaves. With several processes the shards of other
    processes are fetched with `jax.experimental.multihost_utils.process_allgather`, a collective:
    every process must call `gather` on the same arrays.
    """
    for leaf in jax.tree.leaves(tree):
        dtype = getattr(leaf, "dtype", None) or np.asarray(leaf).dtype
        if dtype.kind not in "biufc":
            _checks.fail(
                "tree",
                "a pytree of arrays (numbers or booleans)",
                f"a leaf {type(leaf).__name__} {leaf!r:.40}",
            )
    return jax.tree.map(_to_host, tree)


def _to_host(leaf):
    if isinstance(leaf, jax.Array) and not leaf.is_fully_addressable:
        return _allgather(leaf)
    return np.asarray(leaf)


# --- initialize ------------------------------------------------------------------------------
_ENV = {
    "coordinator": "BSJAX_COORDINATOR",
    "num_processes": "BSJAX_NUM_PROCESSES",
    "process_id": "BSJAX_PROCESS_ID",
}


@declared
def initialize(
    coordinator: str | None = None, num_processes: int | None = None, process_id: int | None = None
) -> bool:
    """Join this process to a multi-process JAX job (`jax.distributed.initialize`).

    Call it first, before any JAX computation, with the same coordinator in every process; the
    same script then runs as one process, several local processes or a cluster job.

    **Arguments** (each falls back on an environment variable when None):
    - `coordinator`: `"host:port"` of process 0's coordinator service (`BSJAX_COORDINATOR`).
    - `num_processes`: number of processes, ≥ 1 (`BSJAX_NUM_PROCESSES`).
    - `process_id`: this process's index in `[0, num_processes)` (`BSJAX_PROCESS_ID`).

    With nothing given or set, JAX's own cluster auto-detection (Slurm, Open MPI, Kubernetes,
    Cloud TPU) starts the job when the environment names a multi-process cluster; otherwise this
    is a no-op. One process (`num_processes=1`) is a no-op too.

    **Returns:** True when it initialised `jax.distributed`; False when there was nothing to do
    (a single process, or already initialised with the same number of processes).
    """
    coordinator = _env_address(coordinator, "coordinator")
    num_processes = _env_int(num_processes, "num_processes")
    process_id = _env_int(process_id, "process_id")
    if num_processes is not None:
        _checks.check_count(num_processes, "num_processes")
    if process_id is not None:
        _checks.check_count(process_id, "process_id", minimum=0)
        if num_processes is not None and process_id >= num_processes:
            _checks.fail("process_id", f"an int in [0, {num_processes}) (num_processes)", process_id)
    if coordinator is not None:
        _check_address(coordinator)
    if jax.distributed.is_initialized():
        if num_processes is not None and num_processes != jax.process_count():
            _checks.fail(
                "num_processes", f"{jax.process_count()} (jax.distributed is running)", num_processes
            )
        return False
    if coordinator is None and num_processes is None and process_id is None:
        if not _cluster_detected():
            return False
        jax.distributed.initialize()
        return True
    if num_processes == 1 and process_id in (None, 0):
        return False
    if not _cluster_detected():
        for name, value in (("coordinator", coordinator), ("num_processes", num_processes)):
            if value is None:
                expected = f"a value (or {_ENV[name]}) outside a detected cluster, with the others set"
                _checks.fail(name, expected, None)
        if process_id is None:
            _checks.fail("process_id", f"an int in [0, {num_processes}) (or BSJAX_PROCESS_ID)", None)
    jax.distributed.initialize(coordinator, num_processes, process_id)
    return True


def _env_address(value, name: str) -> str | None:
    if value is not None:
        if not isinstance(value, str):
            raise TypeError(f"{name}: expected a 'host:port' string, got {type(value).__name__}")
        return value
    return os.environ.get(_ENV[name], "").strip() or None


def _env_int(value, name: str) -> int | None:
    if value is not None:
        return value
    text = os.environ.get(_ENV[name], "").strip()
    if not text:
        return None
    try:
        return int(text)
    except ValueError:
        _checks.fail(_ENV[name], "an int", repr(text))
        raise  # unreachable: `fail` raises


def _check_address(address: str) -> None:
    host, sep, port = address.rpartition(":")
    if not sep or not host or not port.isdigit() or not 0 < int(port) < 65536:
        _checks.fail("coordinator", "'host:port' with a port in 1..65535", repr(address))


def _cluster_detected() -> bool:
    """Whether JAX's own cluster auto-detection finds a job of several processes here.

    Uses JAX's registry of cluster environments (private in JAX, hence the guard): with an
    unknown layout, no cluster is assumed and `initialize` needs its arguments.
    """
    try:
        from jax._src.clusters import ClusterEnv

        for env in ClusterEnv._cluster_types:
            if not env.opt_in_only_method and env.is_env_present():
                return env.get_process_count() > 1
    except Exception:  # a cluster probe that fails means no cluster we can use
        return False
    return False
