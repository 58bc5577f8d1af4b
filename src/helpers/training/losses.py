"""Training loss: (weighted) infoNCE over a query x reference score matrix.

The method weights every query/reference term by how wrong that reference
would be as an answer: w = geodesic(R_q, R_r) / pi for the same object, 1 for
another object. References close in rotation to the query therefore barely
act as negatives.
"""

from __future__ import annotations

import numpy as np
import torch

from ..core.rotations import symmetric_geodesic_deg

WEIGHT_FLOOR = 1e-3
"""Smallest weight used inside the loss.

The positive is the *nearest* reference, whose geodesic weight is small but
can be exactly 0 (query rotation equal to a reference rotation, e.g. a
reference used as a query). Its log weight appears in the numerator, so
w = 0 would make the loss infinite. Clamping to 1e-3 (a 0.18 degree offset)
keeps every term finite while leaving real weights (a few degrees and up,
w >= ~0.01) untouched.
"""


def _as_tensor(x, dtype: torch.dtype, device: torch.device | None = None) -> torch.Tensor:
    if isinstance(x, torch.Tensor):
        return x.to(dtype=dtype, device=device if device is not None else x.device)
    return torch.as_tensor(np.asarray(x), dtype=dtype, device=device)


def pair_weights(q_obj, q_R, r_obj, r_R, symmetries=None) -> torch.Tensor:
    """Loss weights between B queries and M references.

    Args:
        q_obj: (B,) int object ids of the queries.
        q_R: (B, 3, 3) query rotations R_m2c.
        r_obj: (M,) int object ids of the references.
        r_R: (M, 3, 3) reference rotations R_m2c.
        symmetries: None, or a sequence indexed by object id of symmetry groups (None, (K,3,3) or
            :class:`helpers.core.rotations.Symmetries`): same-object pairs of an object with a group
            get the symmetric geodesic, min over S of angle(R_r, R_q S).
        (numpy arrays or tensors; the result lives on q_R's device if it is a
        tensor, else on the CPU.)

    Returns:
        (B, M) float32: geodesic angle / pi (in [0, 1]) for the same object,
        1 for different objects. Not floored (see :data:`WEIGHT_FLOOR`).
    """
    device = q_R.device if isinstance(q_R, torch.Tensor) else None
    qR = _as_tensor(q_R, torch.float64, device)
    rR = _as_tensor(r_R, torch.float64, device)
    qo = _as_tensor(q_obj, torch.int64, device)
    ro = _as_tensor(r_obj, torch.int64, device)
    if qR.ndim != 3 or qR.shape[1:] != (3, 3) or qo.shape != qR.shape[:1]:
        raise ValueError(f"pair_weights: expected q_obj (B,) and q_R (B,3,3), got {tuple(qo.shape)} "
                         f"and {tuple(qR.shape)}")
    if rR.ndim != 3 or rR.shape[1:] != (3, 3) or ro.shape != rR.shape[:1]:
        raise ValueError(f"pair_weights: expected r_obj (M,) and r_R (M,3,3), got {tuple(ro.shape)} "
                         f"and {tuple(rR.shape)}")
    # trace(Rq^T Rr) = sum_ij Rq_ij Rr_ij, then the geodesic angle.
    tr = torch.einsum("bij,mij->bm", qR, rR)
    ang = torch.arccos(((tr - 1.0) / 2.0).clamp(-1.0, 1.0))
    if symmetries is not None:
        ang = _symmetric_angles(ang, qo, qR, ro, rR, symmetries)
    w = torch.where(qo[:, None] == ro[None, :], ang / np.pi, torch.ones_like(ang))
    return w.float()


def _symmetric_angles(ang: torch.Tensor, qo: torch.Tensor, qR: torch.Tensor, ro: torch.Tensor, rR: torch.Tensor,
                      symmetries) -> torch.Tensor:
    """``ang`` (B, M) radians with the same-object pairs of symmetric objects replaced by the symmetric
    geodesic (numpy, on the CPU: a few hundred pairs per step)."""
    out = ang.clone()
    q_obj, r_obj = qo.cpu().numpy(), ro.cpu().numpy()
    q_rot, r_rot = qR.cpu().numpy(), rR.cpu().numpy()
    for o in np.unique(q_obj):
        sym = symmetries[int(o)] if 0 <= int(o) < len(symmetries) else None
        if sym is None:
            continue
        bi, mi = np.nonzero((q_obj[:, None] == o) & (r_obj[None, :] == o))
        if len(bi):
            d = symmetric_geodesic_deg(r_rot[mi], q_rot[bi], sym)
            out[torch.as_tensor(bi), torch.as_tensor(mi)] = torch.as_tensor(np.deg2rad(d), dtype=out.dtype,
                                                                             device=out.device)
    return out


def weighted_info_nce(scores: torch.Tensor, pos: torch.Tensor, weights: torch.Tensor | None = None,
                      tau: float = 0.1, floor: float = WEIGHT_FLOOR) -> torch.Tensor:
    """Mean over queries of -log( w_ip e^{s_ip/tau} / sum_j w_ij e^{s_ij/tau} ).

    Args:
        scores: (B, M) similarity scores.
        pos: (B,) long index of each query's positive column.
        weights: (B, M) non-negative weights, or None for plain infoNCE
            (all weights 1). Clamped below at ``floor`` (see
            :data:`WEIGHT_FLOOR`); with ``floor=0`` a zero weight removes
            the term (log w = -inf), and a zero positive weight gives +inf.
        tau: temperature.

    Returns:
        Scalar loss. Written as logsumexp(s/tau + log w) - (s_ip/tau + log w_ip),
        which is stable for any score range. Note -log w_ip is a constant
        offset (no gradient), so weighted loss values sit above plain ones.
    """
    if scores.ndim != 2:
        raise ValueError(f"scores: expected (B, M), got {tuple(scores.shape)}")
    if tau <= 0:
        raise ValueError(f"tau: expected > 0, got {tau}")
    pos = _as_tensor(pos, torch.int64, scores.device)
    if pos.shape != scores.shape[:1]:
        raise ValueError(f"pos: expected ({scores.shape[0]},), got {tuple(pos.shape)}")
    logits = scores / tau
    if weights is not None:
        weights = _as_tensor(weights, scores.dtype, scores.device)
        if weights.shape != scores.shape:
            raise ValueError(f"weights: expected {tuple(scores.shape)}, got {tuple(weights.shape)}")
        if bool((weights < 0).any()):
            raise ValueError("weights: expected non-negative values")
        logits = logits + torch.log(weights.clamp_min(floor))
    picked = logits.gather(1, pos[:, None]).squeeze(1)
    return (torch.logsumexp(logits, dim=1) - picked).mean()
