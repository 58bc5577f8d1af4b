"""Weighted infoNCE and geodesic pair weights."""

import math

import numpy as np
import pytest
import torch

from helpers.core.rotations import haar_uniform, rot_z
from helpers.training.losses import WEIGHT_FLOOR, pair_weights, weighted_info_nce

S = np.array([[0.5, 0.1, -0.2, 0.3],
              [0.0, 0.4, 0.2, -0.1]])
POS = np.array([0, 1])
W = np.array([[0.05, 1.0, 0.5, 1.0],
              [1.0, 0.1, 0.3, 0.0]])


def _by_hand(scores, pos, weights, tau):
    """Direct formula, term by term, in float64 numpy."""
    losses = []
    for i in range(len(scores)):
        num = weights[i, pos[i]] * math.exp(scores[i, pos[i]] / tau)
        den = sum(weights[i, j] * math.exp(scores[i, j] / tau) for j in range(scores.shape[1]))
        losses.append(-math.log(num / den))
    return float(np.mean(losses))


def test_weighted_loss_matches_hand_computation():
    w = np.maximum(W, WEIGHT_FLOOR)  # the documented floor turns the 0 into 1e-3
    want = _by_hand(S, POS, w, 0.1)
    got = weighted_info_nce(torch.tensor(S), torch.tensor(POS), torch.tensor(W), tau=0.1)
    assert float(got) == pytest.approx(want, rel=1e-10)
    # First row written out in full: -log(0.05 e^5 / (0.05 e^5 + e^1 + 0.5 e^-2 + e^3)).
    row0 = -math.log(0.05 * math.e ** 5 / (0.05 * math.e ** 5 + math.e + 0.5 * math.e ** -2 + math.e ** 3))
    assert _by_hand(S[:1], POS[:1], w[:1], 0.1) == pytest.approx(row0)


def test_plain_info_nce_and_all_ones():
    s, p = torch.tensor(S), torch.tensor(POS)
    plain = weighted_info_nce(s, p, None, tau=0.2)
    assert float(plain) == pytest.approx(_by_hand(S, POS, np.ones_like(S), 0.2), rel=1e-10)
    assert float(weighted_info_nce(s, p, torch.ones_like(s), tau=0.2)) == pytest.approx(float(plain), rel=1e-12)
    ce = torch.nn.functional.cross_entropy(s / 0.2, p)
    assert float(plain) == pytest.approx(float(ce), rel=1e-10)


def test_loss_is_stable_and_finite():
    s = torch.tensor([[1e4, -1e4, 0.0], [-1e4, 1e4, 1e4]], dtype=torch.float32, requires_grad=True)
    w = torch.tensor([[0.0, 1.0, 0.0], [1.0, 0.0, 1.0]])  # zero positive weights -> floor
    loss = weighted_info_nce(s, torch.tensor([0, 1]), w, tau=0.1)
    loss.backward()
    assert torch.isfinite(loss) and torch.isfinite(s.grad).all()
    inf = weighted_info_nce(s.detach(), torch.tensor([0, 1]), w, tau=0.1, floor=0.0)
    assert math.isinf(float(inf))
    with pytest.raises(ValueError):
        weighted_info_nce(s, torch.tensor([0, 1]), -w)


def test_pair_weights_values():
    R0 = haar_uniform(1, 0)[0]
    q_R = np.stack([R0, R0])
    r_R = np.stack([R0, rot_z(np.pi / 2) @ R0, rot_z(np.pi) @ R0, R0])
    w = pair_weights(np.array([0, 1]), q_R, np.array([0, 0, 0, 1]), r_R)
    assert w.shape == (2, 4) and w.dtype == torch.float32
    expected = np.array([[0.0, 0.5, 1.0, 1.0],
                         [1.0, 1.0, 1.0, 0.0]])
    np.testing.assert_allclose(w.numpy(), expected, atol=1e-4)
    # Tensors in, tensors out (same device), symmetric in angle.
    wt = pair_weights(torch.tensor([0]), torch.tensor(r_R[1:2]), torch.tensor([0]), torch.tensor(q_R[:1]))
    assert float(wt) == pytest.approx(0.5, abs=1e-4)
    with pytest.raises(ValueError):
        pair_weights(np.array([0, 1, 2]), q_R, np.array([0]), r_R[:1])
