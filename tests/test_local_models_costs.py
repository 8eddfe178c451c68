"""Costs of the learned-local-model optimiser: derivatives vs finite differences, ramps, expansion."""

import numpy as np
import pytest

from lowcostdex.algos.local_models.costs import (
    ActionCost,
    StateCost,
    SumCost,
    average_expansion,
    quadratic_expansion,
    ramp_weights,
)
from lowcostdex.errors import ConfigError

T, DX, DU = 6, 4, 3


def _trajectory(seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    return rng.normal(size=(T, DX)), rng.normal(size=(T, DU))


def _costs() -> dict[str, object]:
    rng = np.random.default_rng(1)
    target = rng.normal(size=DX)
    weights = np.array([1.0, 0.5, 0.0, 2.0])
    return {
        "l2": StateCost(target, weights, l2=1.5, ramp="linear", final_multiplier=10.0),
        "l1": StateCost(target, weights, l2=0.0, l1=0.7, alpha=0.3, ramp="quadratic"),
        "l1l2": StateCost(target, weights, l2=1.0, l1=0.2, alpha=1e-2),
        "moving": StateCost(rng.normal(size=(T, DX)), weights, l2=0.5, l1=0.3, alpha=0.1),
        "action": ActionCost(
            np.array([1e-3, 0.1, 2.0]), target=np.array([0.5, -1.0, 0.2]), final_multiplier=0.0
        ),
        "moving_action": ActionCost(np.array([0.3, 1.0, 2.0]), target=rng.normal(size=(T, DU))),
        "window": StateCost(
            target, weights, l2=2.0, ramp="final_only", final_steps=3, final_multiplier=5.0
        ),
        "sum": SumCost(
            [StateCost(target, weights, l1=0.4), ActionCost(np.array([0.1, 0.2, 0.3]))],
            weights=[2.0, 0.5],
        ),
    }


def _fd_gradient(fn, y: np.ndarray, h: float = 1e-6) -> np.ndarray:
    grad = np.zeros((fn(y).shape[0], y.shape[-1]))
    for i in range(y.shape[-1]):
        e = np.zeros_like(y)
        e[..., i] = h
        grad[:, i] = (fn(y + e) - fn(y - e)) / (2 * h)
    return grad


@pytest.mark.parametrize(
    "name", ["l2", "l1", "l1l2", "moving", "action", "moving_action", "window", "sum"]
)
def test_cost_derivatives_match_finite_differences(name: str) -> None:
    cost = _costs()[name]
    X, U = _trajectory()
    d = cost.evaluate(X, U)

    def value(y):  # y (T, DX+DU) -> (T,)
        return cost.evaluate(y[:, :DX], y[:, DX:]).value

    def gradient(y):  # -> (T, DX+DU) flattened per coordinate for the Hessian check
        e = cost.evaluate(y[:, :DX], y[:, DX:])
        return np.concatenate([e.lx, e.lu], axis=1)

    y = np.concatenate([X, U], axis=1)
    g = np.concatenate([d.lx, d.lu], axis=1)
    np.testing.assert_allclose(_fd_gradient(value, y).reshape(T, -1), g, atol=1e-6)
    # Hessian: finite differences of the analytic gradient, one column at a time.
    H = np.zeros((T, DX + DU, DX + DU))
    H[:, :DX, :DX] = d.lxx
    H[:, DX:, DX:] = d.luu
    H[:, DX:, :DX] = d.lux
    H[:, :DX, DX:] = np.swapaxes(d.lux, 1, 2)
    h = 1e-6
    for j in range(DX + DU):
        e = np.zeros_like(y)
        e[:, j] = h
        col = (gradient(y + e) - gradient(y - e)) / (2 * h)
        np.testing.assert_allclose(col, H[:, :, j], atol=1e-5)
    assert np.any(np.abs(g) > 1e-3), "test trajectory must give non-trivial gradients"


def test_ramps_shapes_and_endpoints() -> None:
    np.testing.assert_allclose(ramp_weights("constant", 4), [1, 1, 1, 1])
    np.testing.assert_allclose(ramp_weights("linear", 4), [0.25, 0.5, 0.75, 1.0])
    np.testing.assert_allclose(ramp_weights("quadratic", 2, 3.0), [0.25, 3.0])
    np.testing.assert_allclose(ramp_weights("final_only", 3, 10.0), [0, 0, 10.0])
    np.testing.assert_allclose(ramp_weights("final_only", 5, 10.0, final_steps=3), [0, 0, 1, 1, 10])
    with pytest.raises(ConfigError, match="final_only"):
        ramp_weights("exponential", 3)
    with pytest.raises(ConfigError, match="final_steps"):
        ramp_weights("final_only", 3, final_steps=4)


def test_action_cost_with_a_target_per_step() -> None:
    X, U = _trajectory()
    target = np.random.default_rng(4).normal(size=(T, DU))
    w = np.array([0.5, 1.0, 2.0])
    d = ActionCost(w, target=target).evaluate(X, U)
    np.testing.assert_allclose(d.value, 0.5 * np.sum(w * (U - target) ** 2, axis=1))
    np.testing.assert_allclose(d.lu, w * (U - target))
    assert np.all(ActionCost(w, target=U).evaluate(X, U).value == 0.0)
    with pytest.raises(ConfigError, match="steps"):
        ActionCost(w, target=target[:-1]).evaluate(X, U)
    with pytest.raises(ConfigError, match="dU"):
        ActionCost(w, target=np.zeros((T, DU + 1)))


def test_state_cost_final_multiplier_scales_only_last_step() -> None:
    X, U = _trajectory()
    base = StateCost(np.zeros(DX), np.ones(DX)).evaluate(X, U).value
    final = StateCost(np.zeros(DX), np.ones(DX), final_multiplier=10.0).evaluate(X, U).value
    np.testing.assert_allclose(final[:-1], base[:-1])
    assert final[-1] == pytest.approx(10 * base[-1])
    np.testing.assert_allclose(base, 0.5 * np.sum(X**2, axis=1))


def test_quadratic_expansion_reproduces_cost_at_expansion_point_and_nearby() -> None:
    cost = _costs()["l1l2"]
    X, U = _trajectory()
    q = quadratic_expansion(cost.evaluate(X, U), X, U)
    y = np.concatenate([X, U], axis=1)

    def model(yy):
        return 0.5 * np.einsum("ti,tij,tj->t", yy, q.C, yy) + np.einsum("ti,ti->t", q.c, yy) + q.cc

    np.testing.assert_allclose(model(y), cost.evaluate(X, U).value, rtol=1e-12, atol=1e-12)
    # Second-order accurate: error shrinks ~ step^3.
    dy = np.random.default_rng(3).normal(size=y.shape)
    errs = [
        np.max(
            np.abs(model(y + s * dy) - cost.evaluate(X + s * dy[:, :DX], U + s * dy[:, DX:]).value)
        )
        for s in (1e-2, 1e-3)
    ]
    assert errs[1] < errs[0] / 100


def test_average_expansion_is_mean_over_rollouts() -> None:
    cost = _costs()["sum"]
    (X1, U1), (X2, U2) = _trajectory(0), _trajectory(1)
    mean, samples = average_expansion(cost, np.stack([X1, X2]), np.stack([U1, U2]))
    a = quadratic_expansion(cost.evaluate(X1, U1), X1, U1)
    b = quadratic_expansion(cost.evaluate(X2, U2), X2, U2)
    np.testing.assert_allclose(mean.C, 0.5 * (a.C + b.C))
    np.testing.assert_allclose(mean.cc, 0.5 * (a.cc + b.cc))
    np.testing.assert_allclose(samples[1], cost.evaluate(X2, U2).value)


def test_cost_configs_validate() -> None:
    with pytest.raises(ConfigError):
        StateCost(np.zeros(3), np.ones(2))
    with pytest.raises(ConfigError):
        StateCost(np.zeros(2), np.ones(2), alpha=0.0)
    with pytest.raises(ConfigError, match="steps"):
        StateCost(np.zeros((T + 1, DX)), np.ones(DX)).evaluate(*_trajectory())
    with pytest.raises(ConfigError, match="linear"):
        ActionCost(np.ones(2), ramp="cubic")
    with pytest.raises(ConfigError):
        SumCost([ActionCost(np.ones(2))], weights=[1.0, 2.0])
