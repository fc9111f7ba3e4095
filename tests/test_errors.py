"""Bad input → `ValueError` naming the argument, the expected and the received value (SPEC §11)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from bsjax.basis import (
    BSplineSurface,
    basis_functions,
    blending_matrix,
    clamped_knots,
    periodic_blending_matrix,
)
from tests.helpers import random_surface

R, S = 6, 5


@pytest.fixture(scope="module")
def surface():
    return random_surface(np.random.default_rng(0), R, S, 3, 2)


def _make(surface, **change):
    args = dict(
        ctrl=np.asarray(surface.ctrl),
        knots_u=np.asarray(surface.knots_u),
        knots_v=np.asarray(surface.knots_v),
        degree_u=3,
        degree_v=2,
    )
    args.update(change)
    return BSplineSurface(**args)


def _ctrl_nan():
    c = np.zeros((R, S, 3))
    c[2, 3, 1] = np.nan
    return c


def _ctrl_inf():
    c = np.zeros((R, S, 3))
    c[0, 0, 0] = np.inf
    return c


CONSTRUCTOR_CASES = [
    (dict(ctrl=np.zeros((R, S, 2))), "ctrl", "(6, 5, 2)"),
    (dict(ctrl=np.zeros((R * S, 3))), "ctrl", "(30, 3)"),
    (dict(ctrl=_ctrl_nan()), "ctrl", "NaN"),
    (dict(ctrl=_ctrl_inf()), "ctrl", "inf"),
    (dict(degree_u=6), "degree_u", "6"),  # degree >= number of control points
    (dict(degree_u=7, knots_u=np.r_[np.zeros(8), np.ones(6)][:14]), "degree_u", "7"),
    (dict(degree_v=0), "degree_v", "0"),
    (dict(knots_u=np.asarray(clamped_knots(R + 1, 3))), "knots_u", "11"),  # wrong length
    (dict(knots_u=np.r_[0, 0, 0, 0, 0.6, 0.4, 1, 1, 1, 1]), "knots_u", "decrease"),
    (dict(knots_v=np.r_[0, 0, 0.1, 0.4, 0.7, 0.9, 1, 1]), "knots_v", "clamped"),
    (dict(knots_v=np.r_[0, 0, 0, 0.4, 0.7, 2, 2, 2.0]), "knots_v", "[0.0, 2.0]"),
    (dict(knots_u=np.r_[0, 0, 0, 0, 0.5, 0.5 * np.nan, 1, 1, 1, 1]), "knots_u", "NaN"),
    (dict(knots_u=np.r_[0, 0, 0, 0, 0.5, 0.5, 0.5, 0.5, 1, 1, 1, 1][:10]), "knots_u", ""),
    (dict(knots_u=np.zeros((10, 1))), "knots_u", "(10, 1)"),
    (dict(knots_u=None), "knots_u", "None"),
    (dict(weights=np.ones((S, R))), "weights", "(5, 6)"),
    (dict(weights=-np.ones((R, S))), "weights", "-1"),
    (dict(weights=np.full((R, S), np.nan)), "weights", "nan"),
]


@pytest.mark.parametrize("change, name, got", CONSTRUCTOR_CASES)
def test_surface_constructor_errors(surface, change, name, got):
    with pytest.raises(ValueError) as info:
        _make(surface, **change)
    message = str(info.value)
    assert message.startswith(name), message
    assert "expected" in message and got.lower() in message.lower(), message


@pytest.mark.parametrize("change, name, got", CONSTRUCTOR_CASES)
def test_surface_constructor_errors_under_jit(surface, change, name, got):
    """The same errors inside the caller's `jax.jit`, the arrays traced: structure errors while
    tracing, value errors (NaN, decreasing or unclamped knots, negative weights) at run time."""
    args = dict(
        ctrl=np.asarray(surface.ctrl),
        knots_u=np.asarray(surface.knots_u),
        knots_v=np.asarray(surface.knots_v),
        degree_u=3,
        degree_v=2,
        weights=None,
    )
    args.update(change)
    arrays = {k: v for k, v in args.items() if isinstance(v, np.ndarray)}
    fixed = {k: v for k, v in args.items() if k not in arrays}
    with pytest.raises((ValueError, TypeError, jax.errors.JaxRuntimeError), match=f"{name}: expected"):
        jax.block_until_ready(jax.jit(lambda a: BSplineSurface(**fixed, **a))(arrays))


def test_periodic_direction_takes_no_knot_vector(surface):
    with pytest.raises(ValueError, match="^knots_v: expected None"):
        _make(surface, knots_v=np.asarray(surface.knots_v), periodic_v=True)
    with pytest.raises(ValueError, match="^degree_v"):
        BSplineSurface(np.zeros((R, 2, 3)), surface.knots_u, None, 3, 2, periodic_v=True)


def test_non_int_degree_is_a_type_error(surface):
    with pytest.raises(TypeError, match="degree_u"):
        _make(surface, degree_u=3.0)


@pytest.mark.parametrize(
    "call, name",
    [
        (lambda s: s.evaluate(np.zeros(3), np.zeros(4)), "v"),
        (lambda s: s.evaluate(0.5, 0.5, -1, 0), "nu"),
        (lambda s: s.evaluate(0.5, 0.5, 0, -2), "nv"),
        (lambda s: s.normal(np.zeros((2, 2)), np.zeros(4)), "v"),
        (lambda s: s.rows("w", np.zeros(3)), "direction"),
        (lambda s: s.with_ctrl(np.zeros((R, S + 1, 3))), "ctrl"),
        (lambda s: s.with_ctrl(_ctrl_nan()), "ctrl"),
        (lambda s: s.blending(1, 9), "m"),
        (lambda s: s.blending(9, 0), "n"),
        (lambda s: s.blending(params_u=np.zeros((3, 3)), n=9), "params_u"),
        (lambda s: s.blending(9, params_v=np.array([0.0, np.nan, 1.0])), "params_v"),
    ],
)
def test_surface_method_errors(surface, call, name):
    with pytest.raises(ValueError, match=f"^{name}: expected"):
        call(surface)
    with pytest.raises((ValueError, jax.errors.JaxRuntimeError), match=f"{name}: expected"):
        jax.block_until_ready(jax.jit(call)(surface))  # the surface traced


@pytest.mark.parametrize(
    "call, name",
    [
        (lambda b, s: b.points(np.zeros((R, S, 2))), "ctrl"),
        (lambda b, s: b.points(np.zeros((S, R, 3))), "ctrl"),
        (lambda b, s: b.derivative(s.ctrl, 3, 0), "nu, nv"),
        (lambda b, s: b.derivative(s.ctrl, 0, -1), "nu, nv"),
        (lambda b, s: b.refit(np.zeros((9, 8, 3))), "points"),
        (lambda b, s: b.refit(np.zeros((9, 9))), "points"),
        (lambda b, s: b.window(0.01, 0.02, 0.0, 1.0), "window"),
        (lambda b, s: b.window(0.6, 0.2, 0.0, 1.0), "window"),
        (lambda b, s: b.lod(0), "q_u"),
        (lambda b, s: b.lod(2, 1.5), "q_v"),
        (lambda b, s: b.lod(2).refit(np.zeros((5, 5, 3))), "Blending.refit"),  # views carry no inverse
    ],
)
def test_blending_errors(surface, call, name):
    b = surface.blending(9, 9)
    with pytest.raises((ValueError, TypeError), match=f"^{name}: expected"):
        call(b, surface)
    if name != "window":  # a window's size depends on the values: a host-side view (see below)
        with pytest.raises((ValueError, TypeError, jax.errors.JaxRuntimeError), match=f"{name}: expected"):
            jax.block_until_ready(jax.jit(lambda b: call(b, surface))(b))


def test_window_is_host_side(surface):
    """`Blending.window` picks rows by value, so its size is data-dependent: under `jit` it says so."""
    b = surface.blending(9, 9)
    with pytest.raises(TypeError, match="window: expected a concrete Blending"):
        jax.jit(lambda b: b.window(0.0, 0.5, 0.0, 1.0).params_u)(b)


@pytest.mark.parametrize("m, n", [(R - 1, 9), (9, S - 1), (2, 2)])
def test_refit_with_fewer_samples_than_control_points(surface, m, n):
    b = surface.blending(m, n)
    with pytest.raises(ValueError, match=r"^Blending.refit: expected .*m >= r and n >= s.*got grid"):
        b.refit(np.zeros((m, n, 3)))


@pytest.mark.parametrize(
    "call, name",
    [
        (lambda: clamped_knots(3, 3), "degree"),
        (lambda: clamped_knots(5, 0), "degree"),
        (lambda: blending_matrix(np.zeros((4, 2)), 1, np.array([0.5])), "knots"),
        (lambda: blending_matrix(clamped_knots(5, 3), 3, np.zeros((2, 2))), "params"),
        (lambda: blending_matrix(clamped_knots(5, 3), 5, np.array([0.5])), "degree"),
        (lambda: blending_matrix(clamped_knots(5, 3), 3, np.array([0.5]), nu=-1), "nu"),
        (lambda: blending_matrix(clamped_knots(5, 3), 3, np.array([0.5]), nu=1.0), "nu"),
        (lambda: periodic_blending_matrix(3, 3, np.array([0.5])), "degree"),
        (lambda: periodic_blending_matrix(5, 3, np.array([0.5]), nu=-2), "nu"),
        (lambda: periodic_blending_matrix(5, 3, np.zeros((1, 1))), "params"),
    ],
)
def test_basis_function_errors(call, name):
    with pytest.raises((ValueError, TypeError), match=f"^{name}: expected"):  # TypeError: a float order
        call()


def test_rational_evaluate_rejects_bad_derivative_order():
    """A bad `nu` is a ValueError (a float: a TypeError) naming `nu`. The polynomial path does this; the
    NURBS path builds `range(nu + 1)` first and dies with KeyError (nu < 0) / TypeError (float)."""
    surface = random_surface(np.random.default_rng(0), 6, 5, 3, 2, weights=True)
    with pytest.raises(ValueError, match="^nu"):
        surface.evaluate(0.5, 0.5, -1, 0)
    with pytest.raises(TypeError, match="^nu: expected an int"):
        surface.evaluate(0.5, 0.5, 1.5, 0)
    with pytest.raises(ValueError, match="^nv"):
        surface.evaluate(0.5, 0.5, 0, -1)


def test_blending_matrix_rejects_decreasing_knots():
    """SPEC §11: "non-monotone … knot vectors" → clear error. `blending_matrix` (a public
    contract name) only checks ndim and the degree, so a decreasing vector gives a silent matrix."""
    with pytest.raises(ValueError, match="^knots"):
        blending_matrix(np.array([0.0, 0.0, 0.6, 0.3, 1.0, 1.0]), 1, np.array([0.5]))


def test_basis_functions_rejects_negative_derivative_order():
    """`basis_functions` is public (`basis.__all__`); nu = −1 runs degree + 1 Cox–de Boor steps
    and returns a vector one entry short, silently."""
    knots = clamped_knots(6, 3)
    try:
        out = basis_functions(knots, 3, jnp.asarray(0.5), nu=-1)
    except ValueError as error:
        assert str(error).startswith("nu")
        return
    assert out.shape == (6,), out.shape


def test_blending_params_outside_the_domain_are_refused():
    """SPEC §11 / STYLE ("silent dropping of bad input"): explicit `params_u` outside [0, 1]
    are clipped to the ends without a word; a concrete check (like the finite check next to it)
    would name `params_u` and the range."""
    surface = random_surface(np.random.default_rng(2), 6, 5, 3, 2)
    with pytest.raises(ValueError, match="^params_u"):
        surface.blending(params_u=np.array([-0.5, 0.5, 1.5]), n=9)


def test_a_literal_annotation_is_a_set_of_options():
    """`bsjax._declared`: `Literal[...]` accepts its values only — another value of their type is
    a `ValueError` listing them, another type a `TypeError`; with `| None`, None too."""
    from typing import Literal

    from bsjax._declared import declared

    @declared
    def pick(mode: Literal["u", "v"], order: Literal[1, 2] | None = None):
        return mode, order

    assert pick("v", 2) == ("v", 2) and pick("u") == ("u", None)
    with pytest.raises(ValueError, match="mode: expected one of 'u', 'v', got 'w'"):
        pick("w")
    with pytest.raises(TypeError, match="mode: expected one of 'u', 'v', got 1"):
        pick(1)  # pyright: ignore[reportArgumentType]
    with pytest.raises(ValueError, match="order: expected one of 1, 2 or None, got 3"):
        pick("u", 3)  # pyright: ignore[reportArgumentType]
    with pytest.raises(TypeError, match="order: expected one of 1, 2 or None, got True"):
        pick("u", True)  # pyright: ignore[reportArgumentType]
