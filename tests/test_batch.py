"""`bsjax.batch` (issue #14): `map` equals `jax.vmap` on one device, on 4 forced host devices
(sharded output, padding, chunks) and on two `jax.distributed` processes; bad input; `initialize`.

The experiment is a sphere of a batch of centres and radii over a batch of (perturbed) plates:
`collide.contacts` and `Blending.points` per design. Its results are checked against
`jax.vmap`, a Python loop and scipy's B-spline design matrices.
"""

from __future__ import annotations

import functools
import json
import os
import socket
import subprocess
import sys
import textwrap
from pathlib import Path

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.interpolate

from bsjax import batch
from tests.helpers import raises_both

ROOT = Path(__file__).resolve().parents[1]
MARK = "RESULT "


# --- the experiment (also imported by the subprocesses, after their JAX set-up) ---------------
@functools.cache
def experiment(method: str = "window"):
    """`(surface, blending, fn)`: `fn(tool, net)` is one design's contact and sample points
    (`method="dense"`, the same contact, compiles faster: used in the subprocesses)."""
    from bsjax import collide, shapes

    surface = shapes.plate(6, 5)
    blending = surface.blending(9, 7)

    def fn(tool, net):
        contact = collide.contacts(
            blending, net, collide.Sphere(tool["center"], tool["radius"]), method=method
        )
        values = {"area": contact.mask.sum(), "depth": contact.depth, "points": blending.points(net)}
        return values, contact.hit

    return surface, blending, fn


def designs(n: int, seed: int = 0):
    """`n` designs: sphere centres and radii (some apart from the plate) and perturbed nets."""
    rng = np.random.default_rng(seed)
    center = np.c_[rng.uniform(0.2, 0.8, (n, 2)), rng.uniform(-0.15, 0.15, n)]
    center[::3, 2] = 0.6  # every third sphere is apart (the broad phase's early exit)
    radius = rng.uniform(0.1, 0.3, n)
    x, y = np.meshgrid(np.linspace(0, 1, 6), np.linspace(0, 1, 5), indexing="ij")
    net = np.stack([x, y, np.zeros_like(x)], -1)
    nets = net + 0.02 * rng.normal(size=(n, *net.shape))
    return {"center": center, "radius": radius}, nets


def table(out) -> np.ndarray:
    """One row per design: area, max depth, sum of the sample points (host floats)."""
    (values, hit) = batch.gather(out)
    return np.c_[values["area"], values["depth"].max(axis=(1, 2)), values["points"].sum(axis=(1, 2, 3)), hit]


def assert_tree_close(a, b, tol=1e-12):
    assert jax.tree.structure(a) == jax.tree.structure(b)
    for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b)):
        assert np.shape(x) == np.shape(y)
        np.testing.assert_allclose(np.asarray(x, float), np.asarray(y, float), rtol=0, atol=tol)


# --- one device, in process -----------------------------------------------------------------
def test_map_equals_vmap_and_a_loop():
    _, _, fn = experiment()
    tools, nets = designs(8)
    out = batch.map(fn, tools, nets)
    assert_tree_close(out, jax.jit(jax.vmap(fn))(tools, nets))
    for i in (0, 1, 5):  # a design apart (0) and two in contact, each alone
        one = fn(jax.tree.map(lambda x: x[i], tools), nets[i])
        assert_tree_close(jax.tree.map(lambda x: x[i], out), one)
    hits = np.asarray(out[1])
    assert not hits[::3].any() and hits.any()  # the apart designs and some contact: not trivial
    assert out[0]["depth"].sharding.device_set == set(jax.devices())


def test_map_points_match_scipy_design_matrices():
    surface, blending, _ = experiment()
    _, nets = designs(5, seed=1)
    out = batch.map(blending.points, nets)
    du, dv = surface.direction("u"), surface.direction("v")
    a_u = scipy.interpolate.BSpline.design_matrix(np.asarray(blending.params_u), du.knots, du.degree)
    a_v = scipy.interpolate.BSpline.design_matrix(np.asarray(blending.params_v), dv.knots, dv.degree)
    expected = np.einsum("ir,brsk,js->bijk", a_u.toarray(), nets, a_v.toarray())
    np.testing.assert_allclose(np.asarray(out), expected, rtol=0, atol=1e-12)


def test_map_chunks_pad_the_last_and_report_progress():
    _, _, fn = experiment()
    tools, nets = designs(8)
    calls = []
    out = batch.map(fn, tools, nets, chunk=3, progress=lambda done, total: calls.append((done, total)))
    assert calls == [(3, 8), (6, 8), (8, 8)]  # the last chunk of 2 is padded to 3, then cut
    assert_tree_close(out, batch.map(fn, tools, nets))
    whole = []
    batch.map(fn, tools, nets, progress=lambda done, total: whole.append((done, total)))
    assert whole == [(8, 8)]


def test_map_accepts_lists_and_works_inside_jit_and_grad():
    radii = [0.1, 0.2, 0.35]
    fn = lambda r: jnp.stack([r**2, jnp.sin(r)])
    np.testing.assert_allclose(
        np.asarray(batch.map(fn, radii)), np.stack([np.square(radii), np.sin(radii)], 1)
    )
    _, _, contact = experiment("dense")
    tools, nets = designs(6)

    def spill(radius):
        (values, _) = batch.map(contact, {**tools, "radius": radius}, nets, chunk=4)
        return jnp.sum(values["depth"] ** 2)

    @jax.jit
    def spill_vmap(radius):
        (values, _) = jax.vmap(contact)({**tools, "radius": radius}, nets)
        return jnp.sum(values["depth"] ** 2)

    r = jnp.asarray(tools["radius"])
    np.testing.assert_allclose(jax.jit(spill)(r), spill_vmap(r), rtol=1e-12)
    g = jax.grad(spill)(r)
    np.testing.assert_allclose(g, jax.grad(spill_vmap)(r), rtol=1e-10, atol=1e-14)
    eps = 1e-6 * np.eye(6)[2]
    fd = (spill_vmap(r + eps) - spill_vmap(r - eps)) / 2e-6
    np.testing.assert_allclose(g[2], fd, rtol=1e-5)
    assert g[2] > 0 and g[0] == 0  # a deeper sphere, more depth; a sphere apart, no gradient


def test_map_reuses_its_compilation():
    calls = []

    def fn(x):
        calls.append(1)  # runs once per trace
        return 2 * x

    for n in (4, 4, 4):
        np.testing.assert_array_equal(np.asarray(batch.map(fn, np.arange(n, dtype=float))), 2 * np.arange(n))
    assert len(calls) == 1


class _Scaled(eqx.Module):
    scale: jax.Array
    power: int = eqx.field(static=True)

    def __call__(self, x):
        return self.scale * x**self.power


def test_map_bound_values_are_arguments_not_stale_constants():
    """A partial or bound method over new arrays of the same shapes reuses one compilation and
    uses the new values; a new static bound value (an int) compiles anew."""
    traces = []

    def scaled(scale, x, power=1):
        traces.append(power)  # runs once per trace
        return scale * x**power

    x = np.arange(1.0, 5.0)
    for scale in (2.0, 3.0):
        out = batch.map(functools.partial(scaled, jnp.asarray(scale)), x)
        np.testing.assert_array_equal(np.asarray(out), scale * x)
    np.testing.assert_array_equal(np.asarray(batch.map(functools.partial(scaled, 2.0, power=2), x)), 2 * x**2)
    assert traces == [1, 2]
    for scale in (5.0, 7.0):
        np.testing.assert_array_equal(np.asarray(batch.map(_Scaled(jnp.asarray(scale), 3), x)), scale * x**3)
    surface, blending, _ = experiment()
    _, nets = designs(3)
    other = surface.blending(9, 7, params_u=np.linspace(0, 1, 9) ** 2)  # same shapes, other samples
    np.testing.assert_allclose(
        np.asarray(batch.map(other.points, nets)), np.asarray(jax.vmap(other.points)(nets)), atol=1e-12
    )
    assert not np.allclose(
        np.asarray(batch.map(blending.points, nets)), np.asarray(batch.map(other.points, nets))
    )


def test_gather_returns_numpy():
    out = batch.gather(batch.map(lambda x: {"y": x * 3}, np.arange(4.0)))
    assert isinstance(out["y"], np.ndarray)
    np.testing.assert_array_equal(out["y"], 3 * np.arange(4.0))


def test_mesh():
    grid = batch.mesh()
    assert grid.axis_names == ("batch",) and list(grid.devices) == jax.devices()
    assert batch.mesh(jax.devices()[:1]).size == 1
    with pytest.raises(TypeError, match="devices: expected a non-empty sequence of jax devices"):
        batch.mesh([])


# --- bad input ------------------------------------------------------------------------------
def test_map_bad_input():
    _, _, fn = experiment()
    tools, nets = designs(4)
    raises_both(lambda t, p: batch.map(fn, t, p), tools, nets[:3], match=r"args\[1\]: expected leading")
    raises_both(
        lambda c, p: batch.map(fn, {"center": c, "radius": c[:, 0]}, p),
        tools["center"][:0],
        nets[:0],
        match=r"args\[0\]\['center'\]: expected a non-empty batch .* got shape \(0, 3\)",
    )
    raises_both(
        lambda p: batch.map(fn, {"center": 1.0}, p), nets, match=r"args\[0\]\['center'\]: expected an array"
    )
    with pytest.raises(TypeError, match="fn: expected a callable"):
        batch.map(3, nets)
    with pytest.raises(ValueError, match="args: expected at least one array"):
        batch.map(fn)
    with pytest.raises(ValueError, match="chunk: expected an int >= 1, got 0"):
        batch.map(fn, tools, nets, chunk=0)
    with pytest.raises(TypeError, match="chunk: expected an int"):
        batch.map(fn, tools, nets, chunk=2.5)
    with pytest.raises(TypeError, match="progress: expected a callable"):
        batch.map(fn, tools, nets, progress=True)
    with pytest.raises(TypeError, match="mesh: expected a jax.sharding.Mesh"):
        batch.map(fn, tools, nets, mesh=jax.devices())


def test_map_value_check_of_fn_raises():
    _, _, fn = experiment("dense")
    tools, nets = designs(4)
    nets[2, 1, 1, 2] = np.nan
    raises_both(lambda p: batch.map(fn, tools, p), nets, match="ctrl: expected finite values")


# --- initialize -----------------------------------------------------------------------------
@pytest.fixture
def no_cluster(monkeypatch):
    for name in ("BSJAX_COORDINATOR", "BSJAX_NUM_PROCESSES", "BSJAX_PROCESS_ID"):
        monkeypatch.delenv(name, raising=False)
    monkeypatch.setattr(batch, "_cluster_detected", lambda: False)
    return monkeypatch


def test_initialize_single_process_is_a_no_op(no_cluster):
    assert batch.initialize() is False
    assert batch.initialize(num_processes=1) is False
    no_cluster.setenv("BSJAX_NUM_PROCESSES", "1")
    assert batch.initialize() is False
    assert not jax.distributed.is_initialized()


def test_initialize_passes_arguments_and_environment_to_jax(no_cluster):
    """What reaches `jax.distributed.initialize` (recorded, not started: it runs once per
    process; the real start is the two-process test below)."""
    calls = []
    no_cluster.setattr(jax.distributed, "initialize", lambda *a: calls.append(a))
    assert batch.initialize("127.0.0.1:1234", 2, 1) is True
    no_cluster.setenv("BSJAX_COORDINATOR", "10.0.0.1:99")
    no_cluster.setenv("BSJAX_NUM_PROCESSES", "3")
    no_cluster.setenv("BSJAX_PROCESS_ID", "2")
    assert batch.initialize() is True
    assert batch.initialize(process_id=0) is True  # an argument wins over its variable
    for name in ("BSJAX_COORDINATOR", "BSJAX_NUM_PROCESSES", "BSJAX_PROCESS_ID"):
        no_cluster.delenv(name)
    no_cluster.setattr(batch, "_cluster_detected", lambda: True)  # e.g. a Slurm job of 4 tasks
    assert batch.initialize() is True
    assert batch.initialize(num_processes=4) is True  # JAX's detection fills in the rest
    assert calls == [
        ("127.0.0.1:1234", 2, 1),
        ("10.0.0.1:99", 3, 2),
        ("10.0.0.1:99", 3, 0),
        (),
        (None, 4, None),
    ]


def test_initialize_bad_input(no_cluster):
    with pytest.raises(ValueError, match=r"process_id: expected an int in \[0, 2\).*got 2"):
        batch.initialize("127.0.0.1:1234", 2, 2)
    with pytest.raises(ValueError, match="coordinator: expected 'host:port'.*got 'localhost'"):
        batch.initialize("localhost", 2, 0)
    with pytest.raises(TypeError, match="coordinator: expected a string or None, got 1234"):
        batch.initialize(1234, 2, 0)
    with pytest.raises(ValueError, match="coordinator: expected a value .*BSJAX_COORDINATOR.*got None"):
        batch.initialize(num_processes=2, process_id=0)
    with pytest.raises(ValueError, match="num_processes: expected a value .*got None"):
        batch.initialize("127.0.0.1:1234", process_id=0)
    with pytest.raises(
        ValueError, match=r"process_id: expected an int in \[0, 2\).*BSJAX_PROCESS_ID.*got None"
    ):
        batch.initialize("127.0.0.1:1234", 2)
    with pytest.raises(ValueError, match="num_processes: expected an int >= 1, got 0"):
        batch.initialize("127.0.0.1:1234", 0, 0)
    no_cluster.setenv("BSJAX_NUM_PROCESSES", "two")
    with pytest.raises(ValueError, match="BSJAX_NUM_PROCESSES: expected an int, got 'two'"):
        batch.initialize()
    assert not jax.distributed.is_initialized()


# --- several devices and processes (subprocesses) --------------------------------------------
def _python(code: str, env: dict, *args: str) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-c", textwrap.dedent(code), *args],
        cwd=ROOT,
        env={**os.environ, **env},
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


def _result(proc: subprocess.Popen, timeout: float = 120) -> dict:
    try:
        out, err = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        proc.kill()
        out, err = proc.communicate()
        pytest.fail(f"subprocess timed out\n{out}\n{err[-3000:]}")
    assert proc.returncode == 0, err[-3000:]
    lines = [line for line in out.splitlines() if line.startswith(MARK)]
    assert lines, out + err[-3000:]
    return json.loads(lines[-1][len(MARK) :])


FOUR_DEVICES = f"""
    import json
    import jax, numpy as np
    jax.config.update("jax_enable_x64", True)
    from bsjax import batch
    from tests.test_batch import experiment, designs, table
    _, _, fn = experiment("dense")
    found = {{"devices": len(jax.devices())}}
    tools, nets = designs(8)
    out = batch.map(fn, tools, nets)
    ref = jax.jit(jax.vmap(fn))(tools, nets)
    depth = out[0]["depth"]
    found["device_set"] = len(depth.sharding.device_set)
    found["spec"] = list(depth.sharding.spec)
    found["shards"] = sorted(
        (s.device.id, s.index[0].start, s.index[0].stop,
         float(np.max(np.abs(np.asarray(s.data) - np.asarray(ref[0]["depth"])[s.index]))))
        for s in depth.addressable_shards)
    gap = lambda a, b: max(float(np.max(np.abs(np.asarray(x, float) - np.asarray(y, float))))
                          for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b)))
    found["gap8"] = gap(out, ref)
    found["table8"] = table(out).tolist()
    tools7, nets7 = jax.tree.map(lambda x: x[:7], (tools, nets))
    out7 = batch.map(fn, tools7, nets7)
    found["gap7"] = gap(out7, jax.jit(jax.vmap(fn))(tools7, nets7))
    found["shape7"] = list(out7[0]["depth"].shape)
    calls = []
    chunked = batch.map(fn, tools7, nets7, chunk=3, progress=lambda d, t: calls.append([d, t]))
    found["gap7_chunked"], found["calls"] = gap(chunked, out7), calls
    def spill(radius, over):
        (values, _) = over({{**tools7, "radius": radius}}, nets7)
        return jax.numpy.sum(values["depth"] ** 2)

    r7 = jax.numpy.asarray(tools7["radius"])  # padded batch: the cotangent comes back replicated
    sharded = jax.grad(spill)(r7, lambda *a: batch.map(fn, *a))
    found["grad_gap"] = gap(sharded, jax.grad(spill)(r7, jax.vmap(fn)))
    nets[5, 2, 2, 2] = np.nan
    try:
        jax.block_until_ready(batch.map(fn, tools, nets))
        found["nan"] = "no error"
    except ValueError as err:
        found["nan"] = str(err)
    print("{MARK}" + json.dumps(found), flush=True)
"""


def test_map_on_four_devices():
    found = _result(_python(FOUR_DEVICES, {"XLA_FLAGS": "--xla_force_host_platform_device_count=4"}))
    assert found["devices"] == 4 and found["device_set"] == 4 and found["spec"] == ["batch"]
    assert [s[:3] for s in found["shards"]] == [[0, 0, 2], [1, 2, 4], [2, 4, 6], [3, 6, 8]]
    assert max(s[3] for s in found["shards"]) <= 1e-12  # each device holds its own block
    assert found["gap8"] <= 1e-12 and found["gap7"] <= 1e-12 and found["shape7"] == [7, 9, 7]
    assert found["gap7_chunked"] <= 1e-12 and found["calls"] == [[4, 7], [7, 7]]  # chunk 3 → 4
    assert found["grad_gap"] <= 1e-12
    assert found["nan"].startswith("ctrl: expected finite values")  # an error, not a hang
    _, _, fn = experiment("dense")
    np.testing.assert_allclose(found["table8"], table(jax.jit(jax.vmap(fn))(*designs(8))), rtol=0, atol=1e-12)


WORKER = f"""
    import json, sys
    from bsjax import batch
    started = batch.initialize(*json.loads(sys.argv[1]))
    import jax, numpy as np
    jax.config.update("jax_enable_x64", True)
    from tests.test_batch import experiment, designs, table
    _, _, fn = experiment("dense")
    tools, nets = designs(8)
    out = batch.map(fn, tools, nets)
    found = {{"started": started, "process": jax.process_index(), "count": jax.process_count(),
             "devices": len(jax.devices()), "local": len(out[0]["depth"].addressable_shards),
             "global": len(out[0]["depth"].sharding.device_set), "table8": table(out).tolist()}}
    tools7, nets7 = jax.tree.map(lambda x: x[:7], (tools, nets))
    found["table7"] = table(batch.map(fn, tools7, nets7, chunk=3)).tolist()
    points = batch.map(experiment("dense")[1].points, nets7)  # bound arrays: global, replicated
    found["points7"] = batch.gather(points).sum(axis=(1, 2, 3)).tolist()
    print("{MARK}" + json.dumps(found), flush=True)
"""


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_map_on_two_processes_matches_one():
    """Two processes × 2 CPU devices over 127.0.0.1: process 0 configured by the environment,
    process 1 by arguments; both gather the same tables as this single process."""
    address = f"127.0.0.1:{_free_port()}"
    flags = {"XLA_FLAGS": "--xla_force_host_platform_device_count=2"}
    env0 = {**flags, "BSJAX_COORDINATOR": address, "BSJAX_NUM_PROCESSES": "2", "BSJAX_PROCESS_ID": "0"}
    procs = [_python(WORKER, env0, "[]"), _python(WORKER, flags, json.dumps([address, 2, 1]))]
    try:
        found = [_result(p) for p in procs]
    finally:
        for p in procs:
            if p.poll() is None:
                p.kill()
    _, _, fn = experiment("dense")
    tools, nets = designs(8)
    expected8 = table(jax.jit(jax.vmap(fn))(tools, nets))
    expected7 = table(jax.jit(jax.vmap(fn))(*jax.tree.map(lambda x: x[:7], (tools, nets))))
    for i, f in enumerate(found):
        assert f["started"] and f["process"] == i and f["count"] == 2 and f["devices"] == 4
        assert f["local"] == 2 and f["global"] == 4  # each process holds 2 of the 4 blocks
        np.testing.assert_allclose(f["table8"], expected8, rtol=0, atol=1e-12)
        np.testing.assert_allclose(f["table7"], expected7, rtol=0, atol=1e-12)
        np.testing.assert_allclose(f["points7"], expected7[:, 2], rtol=0, atol=1e-12)
    assert found[0]["table8"] == found[1]["table8"] and found[0]["table7"] == found[1]["table7"]
