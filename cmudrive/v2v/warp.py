"""Warp a partner's BEV occupancy into the ego's frame and merge it with the ego's own.

Both grids follow :class:`cmudrive.sensors.occupancy.OccupancyConfig` (ego frame at the vehicle centre,
x forward, y left; row 0 at x = ``ahead``, column 0 at y = ``side``). For every ego cell the warp takes
its centre's ego-frame point p_e, maps it to the partner's frame with the two poses,

    p_w = R(yaw_e) p_e + t_e,        p_p = R(yaw_p)^T (p_w - t_p),

and reads the partner cell that contains p_p (nearest-neighbour resampling; cells outside the partner's
grid read empty). This is the same map as HEAL's ``normalize_pairwise_tfm`` + ``F.affine_grid`` +
``F.grid_sample(mode="nearest", align_corners=False)`` with the pairwise transform T_p<-e =
inv(T_w<-p) T_w<-e, written out in metres instead of [-1, 1] grid units, so there is no normalisation
to get wrong. The merge is an element-wise OR per class.
"""

from __future__ import annotations

import numba
import numpy as np

from cmudrive.sensors.occupancy import OccupancyConfig


def warp_to_ego(
    partner_grid: np.ndarray,
    partner_pose: np.ndarray,
    ego_pose: np.ndarray,
    config: OccupancyConfig | None = None,
) -> np.ndarray:
    """Partner grids (n, C, H, W) seen from ego poses: poses are (n, 3) x [m], y [m], yaw [rad] in the
    map frame; returns (n, C, H, W) bool in each ego's frame."""
    config = config or OccupancyConfig()
    partner_grid = np.asarray(partner_grid, np.bool_)
    if partner_grid.ndim != 4 or partner_grid.shape[2:] != config.shape:
        raise ValueError(f"partner grids have shape {partner_grid.shape}, expected (n, C, {config.shape})")
    partner_pose = np.asarray(partner_pose, np.float64).reshape(-1, 3)
    ego_pose = np.asarray(ego_pose, np.float64).reshape(-1, 3)
    return _warp(partner_grid, partner_pose, ego_pose, config.resolution, config.ahead, config.side)


def merge(own: np.ndarray, warped: np.ndarray, has_partner: np.ndarray | None = None) -> np.ndarray:
    """Element-wise OR of the ego's own grids and the warped partner grids (n, C, H, W); rows where
    ``has_partner`` (n,) is False keep the own grid."""
    if has_partner is None:
        return own | warped
    return own | (warped & np.asarray(has_partner, bool)[:, None, None, None])


@numba.njit(cache=True)
def _warp(
    src: np.ndarray, src_pose: np.ndarray, dst_pose: np.ndarray, res: float, ahead: float, side: float
) -> np.ndarray:
    n, c, h, w = src.shape
    out = np.zeros((n, c, h, w), np.bool_)
    for i in range(n):
        ce, se = np.cos(dst_pose[i, 2]), np.sin(dst_pose[i, 2])
        cp, sp = np.cos(src_pose[i, 2]), np.sin(src_pose[i, 2])
        # ego frame -> partner frame: p_p = R_p^T (R_e p_e + t_e - t_p) = A p_e + b
        a00, a01 = cp * ce + sp * se, -cp * se + sp * ce
        a10, a11 = -sp * ce + cp * se, sp * se + cp * ce
        tx, ty = dst_pose[i, 0] - src_pose[i, 0], dst_pose[i, 1] - src_pose[i, 1]
        b0, b1 = cp * tx + sp * ty, -sp * tx + cp * ty
        for r in range(h):
            xe = ahead - (r + 0.5) * res
            for col in range(w):
                ye = side - (col + 0.5) * res
                xp = a00 * xe + a01 * ye + b0
                yp = a10 * xe + a11 * ye + b1
                rp = int(np.floor((ahead - xp) / res))
                cq = int(np.floor((side - yp) / res))
                if 0 <= rp < h and 0 <= cq < w:
                    for k in range(c):
                        out[i, k, r, col] = src[i, k, rp, cq]
    return out
