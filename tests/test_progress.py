"""Progress callbacks of long work (issue #14, deliverable 6): `mss.simulate`/`trajectory`,
`vsofm.fit`, `merge.refit`/`refine`/`merge(refine=True)` call `progress(done, total)` as they
run, in order, inside a caller's `jit`, `vmap` and `grad` too; the results are bit-identical with
and without a callback, and without one the compiled program holds no callback at all.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from bsjax import batch, merge, mss, shapes, vsofm
from bsjax.examples import merge_cases


class Recorder:
    """A progress callback that keeps its calls (one object: one compilation)."""

    def __init__(self):
        self.calls: list[tuple[int, int]] = []

    def __call__(self, done: int, total: int) -> None:
        self.calls.append((done, total))


def _jelly():
    x = np.stack(np.meshgrid(*[np.linspace(0.0, 0.01, 3)] * 3, indexing="ij"), -1)
    lattice = mss.hex_lattice(x, material=mss.JELLY)
    return lattice, mss.init(lattice), 0.5 * float(mss.stable_dt(lattice)), jnp.array([0.0, 0.0, -9.81])


def _callbacks(jaxpr) -> int:
    return str(jaxpr).count("debug_callback")


def test_simulate_reports_chunks_and_the_result_is_identical():
    lattice, state, dt, g = _jelly()
    seen = Recorder()
    plain = mss.simulate(lattice, state, dt, 250, gravity=g)
    shown = mss.simulate(lattice, state, dt, 250, gravity=g, progress=seen)
    np.testing.assert_array_equal(np.asarray(shown.position), np.asarray(plain.position))
    np.testing.assert_array_equal(np.asarray(shown.velocity), np.asarray(plain.velocity))
    assert seen.calls == [(d, 250) for d in range(3, 250, 3)] + [(250, 250)]  # ⌈250/100⌉ = 3 steps
    seen.calls.clear()
    chunked = mss.simulate(lattice, state, dt, 250, gravity=g, progress=seen, checkpoint_every=40)
    np.testing.assert_array_equal(np.asarray(chunked.position), np.asarray(plain.position))
    assert seen.calls == [(40, 250), (80, 250), (120, 250), (160, 250), (200, 250), (240, 250), (250, 250)]


def test_a_new_callback_per_call_reuses_the_program_and_reports_to_its_own_caller():
    """A direct call keys its program by "a callback", not by the callable: a fresh bar per call
    (the CLI's, a user's tqdm) compiles nothing new, and each call's reports reach its own
    callback (not an earlier one's) — from two threads at once too, and from a call made inside
    a callback (neither waits for the other)."""
    import threading

    lattice, state, dt, g = _jelly()
    compiled = []
    jax.monitoring.register_event_duration_secs_listener(
        lambda event, duration, **kw: (
            compiled.append(event) if event.endswith("backend_compile_duration") else None
        )
    )
    first, second = Recorder(), Recorder()
    mss.simulate(lattice, state, dt, 40, gravity=g, progress=first)
    before = len(compiled)
    mss.simulate(lattice, state, dt, 40, gravity=g, progress=second)
    mss.simulate(
        lattice, state, dt, 40, gravity=g, progress=lambda done, total: second.calls.append((-done, total))
    )
    assert len(compiled) == before  # no new program for a new callable
    assert first.calls == [(d, 40) for d in range(1, 41)]
    assert second.calls == [(d, 40) for d in range(1, 41)] + [(-d, 40) for d in range(1, 41)]
    mine = [Recorder(), Recorder()]
    threads = [
        threading.Thread(target=lambda r=r: mss.simulate(lattice, state, dt, 40, gravity=g, progress=r))
        for r in mine
    ]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert mine[0].calls == mine[1].calls == [(d, 40) for d in range(1, 41)]
    inner = Recorder()

    def outer(done, total):
        if done == 1:
            mss.simulate(lattice, state, dt, 40, gravity=g, progress=inner)

    mss.simulate(lattice, state, dt, 40, gravity=g, progress=outer)
    assert inner.calls == [(d, 40) for d in range(1, 41)]


def test_trajectory_reports_each_saved_state():
    lattice, state, dt, g = _jelly()
    seen = Recorder()
    final, saved = mss.trajectory(lattice, state, dt, 100, gravity=g, save_every=25, progress=seen)
    final0, saved0 = mss.trajectory(lattice, state, dt, 100, gravity=g, save_every=25)
    np.testing.assert_array_equal(np.asarray(saved.position), np.asarray(saved0.position))
    np.testing.assert_array_equal(np.asarray(final.position), np.asarray(final0.position))
    assert seen.calls == [(25, 100), (50, 100), (75, 100), (100, 100)]


def test_no_callback_adds_nothing_to_the_program():
    """Without a callback the rollout's program is the one without the feature: no host
    callback (nothing to wait for); with one, one callback site per chunk loop."""
    lattice, state, dt, g = _jelly()

    def run(progress):
        return jax.make_jaxpr(lambda s: mss.simulate(lattice, s, dt, 250, gravity=g, progress=progress))(
            state
        )

    assert _callbacks(run(None)) == 0
    assert _callbacks(run(Recorder())) > 0
    assert "scan" in str(run(None)) and str(run(None)).count("scan") < str(run(Recorder())).count("scan")


def test_progress_inside_jit_vmap_and_grad():
    lattice, state, dt, g = _jelly()
    seen = Recorder()

    def height(z, progress):
        moved = mss.State(state.position + z, state.velocity)
        return jnp.mean(mss.simulate(lattice, moved, dt, 40, gravity=g, progress=progress).position[:, 2])

    value = jax.jit(lambda z: height(z, seen))(jnp.asarray(0.001))
    assert seen.calls == [(d, 40) for d in range(1, 41)]
    # the same rollout in another program (the callbacks change XLA's fusion): equal to rounding
    assert float(value) == pytest.approx(float(height(jnp.asarray(0.001), None)), rel=1e-13)
    seen.calls.clear()
    grad = jax.grad(lambda z: height(z, seen))(jnp.asarray(0.001))
    assert float(grad) == pytest.approx(1.0, abs=1e-9)  # a rigid shift: d mean z / dz = 1
    assert seen.calls[-1] == (40, 40)
    seen.calls.clear()
    heights = jax.vmap(lambda z: height(z, seen))(jnp.asarray([0.0, 0.001]))
    assert float(heights[1] - heights[0]) == pytest.approx(0.001, abs=1e-12)
    assert seen.calls.count((40, 40)) == 2  # the state is batched: once per design


def test_vsofm_fit_reports_cycles_and_the_nodes_are_identical():
    ball = shapes.sphere(radius=1.0, n_rows=6, n_around=6)
    points = np.asarray(ball.blending(8, 8).points(ball.ctrl)).reshape(-1, 3)
    seen = Recorder()
    shown = vsofm.fit(points, (3, 3, 3), cycles=6, progress=seen)
    plain = vsofm.fit(points, (3, 3, 3), cycles=6)
    np.testing.assert_array_equal(np.asarray(shown), np.asarray(plain))
    assert seen.calls == [(d, 6) for d in range(1, 7)]
    with pytest.raises(TypeError, match="progress: expected a callable"):
        vsofm.fit(points, (3, 3, 3), cycles=6, progress=3)  # type: ignore[arg-type]


def test_merge_refit_reports_rounds_and_the_net_is_identical():
    patches = merge_cases.case(1).patches
    layout = merge.plan(patches, "u", 1, samples=12, orient="as_given")
    ctrls = [p.ctrl for p in patches]
    solver = merge.RefitSolver(rounds=3, rtol=0.0)
    seen = Recorder()
    shown = merge.refit(layout, ctrls, solver, progress=seen)
    plain = merge.refit(layout, ctrls, solver)
    np.testing.assert_array_equal(np.asarray(shown.ctrl), np.asarray(plain.ctrl))
    np.testing.assert_array_equal(np.asarray(shown.rms), np.asarray(plain.rms))
    assert seen.calls == [(1, 3), (2, 3), (3, 3)] and int(shown.rounds) == 3
    seen.calls.clear()
    merged = merge.merge(patches, "u", 1, samples=12, orient="as_given", refine=True, progress=seen)
    assert seen.calls[-1][1] == 8 and [d for d, _ in seen.calls] == list(range(1, len(seen.calls) + 1))
    np.testing.assert_array_equal(
        np.asarray(merged.ctrl),
        np.asarray(merge.merge(patches, "u", 1, samples=12, orient="as_given", refine=True).ctrl),
    )
    with pytest.raises(TypeError, match="progress: expected a callable"):
        merge.refit(layout, ctrls, solver, progress="bar")  # type: ignore[arg-type]


def test_report_concrete_and_traced():
    seen = Recorder()
    batch.report_progress(seen, 2, 5)
    batch.report_progress(None, 2, 5)
    jax.block_until_ready(jax.jit(lambda x: (batch.report_progress(seen, 3, 5, after=x), x)[1])(jnp.ones(2)))
    assert seen.calls == [(2, 5), (3, 5)]
