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
    partner_grid, partner_pose, ego_pose = _checked(partner_grid, partner_pose, ego_pose, config)
    out = np.zeros_like(partner_grid)
    cfg = config or OccupancyConfig()
    _warp_or(
        partner_grid,
        partner_pose,
        ego_pose,
        np.ones(len(out), np.bool_),
        cfg.resolution,
        cfg.ahead,
        cfg.side,
        out,
    )
    return out


def warp_and_merge(
    own: np.ndarray,
    partner_grid: np.ndarray,
    partner_pose: np.ndarray,
    ego_pose: np.ndarray,
    has_partner: np.ndarray,
    config: OccupancyConfig | None = None,
) -> np.ndarray:
    """``merge(own, warp_to_ego(...), has_partner)`` in one pass over the grids (what the link runs)."""
    partner_grid, partner_pose, ego_pose = _checked(partner_grid, partner_pose, ego_pose, config)
    out = np.array(own, np.bool_, copy=True)
    cfg = config or OccupancyConfig()
    _warp_or(
        partner_grid,
        partner_pose,
        ego_pose,
        np.asarray(has_partner, np.bool_),
        cfg.resolution,
        cfg.ahead,
        cfg.side,
        out,
    )
    return out


def merge(own: np.ndarray, warped: np.ndarray, has_partner: np.ndarray | None = None) -> np.ndarray:
    """Element-wise OR of the ego's own grids and the warped partner grids (n, C, H, W); rows where
    ``has_partner`` (n,) is False keep the own grid."""
    if has_partner is None:
        return own | warped
    return own | (warped & np.asarray(has_partner, bool)[:, None, None, None])


def _checked(
    grid: np.ndarray, partner_pose: np.ndarray, ego_pose: np.ndarray, config: OccupancyConfig | None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    shape = (config or OccupancyConfig()).shape
    grid = np.ascontiguousarray(grid, np.bool_)
    if grid.ndim != 4 or grid.shape[2:] != shape:
        raise ValueError(f"partner grids have shape {grid.shape}, expected (n, C, {shape[0]}, {shape[1]})")
    partner_pose = np.asarray(partner_pose, np.float64).reshape(-1, 3)
    ego_pose = np.asarray(ego_pose, np.float64).reshape(-1, 3)
    if not len(partner_pose) == len(ego_pose) == len(grid):
        raise ValueError(f"{len(grid)} grids, {len(partner_pose)} partner poses, {len(ego_pose)} ego poses")
    return grid, partner_pose, ego_pose


@numba.njit(cache=True)
def _warp_or(
    src: np.ndarray,  # (n, C, H, W) partner grids
    src_pose: np.ndarray,  # (n, 3)
    dst_pose: np.ndarray,  # (n, 3)
    use: np.ndarray,  # (n,) bool: warp this row
    res: float,
    ahead: float,
    side: float,
    out: np.ndarray,  # (n, C, H, W): the warped cells are ORed into it
) -> None:
    n, c, h, w = src.shape
    for i in range(n):
        if not use[i]:
            continue
        ce, se = np.cos(dst_pose[i, 2]), np.sin(dst_pose[i, 2])
        cp, sp = np.cos(src_pose[i, 2]), np.sin(src_pose[i, 2])
        # ego frame -> partner frame: p_p = R_p^T (R_e p_e + t_e - t_p) = A p_e + b
        a00, a01 = cp * ce + sp * se, -cp * se + sp * ce
        a10, a11 = -sp * ce + cp * se, sp * se + cp * ce
        tx, ty = dst_pose[i, 0] - src_pose[i, 0], dst_pose[i, 1] - src_pose[i, 1]
        b0, b1 = cp * tx + sp * ty, -sp * tx + cp * ty
        packed = np.zeros((h, w), np.uint8)  # the classes of a cell as bits: one read per cell below
        for k in range(c):
            bit = np.uint8(1 << k)
            for r in range(h):
                for col in range(w):
                    if src[i, k, r, col]:
                        packed[r, col] |= bit
        for r in range(h):
            xe = ahead - (r + 0.5) * res
            for col in range(w):
                ye = side - (col + 0.5) * res
                rp = int(np.floor((ahead - (a00 * xe + a01 * ye + b0)) / res))
                cq = int(np.floor((side - (a10 * xe + a11 * ye + b1)) / res))
                if 0 <= rp < h and 0 <= cq < w and packed[rp, cq]:
                    bits = packed[rp, cq]
                    for k in range(c):
                        if bits & (1 << k):
                            out[i, k, r, col] = True
