"""Numba kernels of the front camera: a z-buffered triangle rasteriser batched over cameras, and the
per-pixel weather / light pass. See :mod:`cmudrive.sensors.camera` for the model and the conventions.

Camera frame (OpenCV): x right, y down, z forward [m]; pixel (row r, col c) has its centre at image
coordinates (u, v) = (c + 0.5, r + 0.5), u = fx x / z + cx, v = fy y / z + cy. The depth buffer holds z
(distance along the optical axis) [m], +inf for sky. Triangles carry a ``keep`` factor (1 - depth bias):
the z-test compares ``z * keep``, so coplanar layers on the ground (road over grass, markings over road)
win by layer instead of z-fighting; the stored depth is that biased value (at most 0.3 % short).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

FLAG_EMISSIVE = 1  # lamps: not darkened at night
FLAG_ROAD = 2  # paved surfaces: darker and glossy when wet
FLAG_SKY = 4
FLAG_GRASS = 8  # the ground plane outside the map's surfaces


@njit(cache=True, fastmath=True)
def _fill(x0, y0, z0, x1, y1, z1, x2, y2, z2, r, g, b, flag, keep, rgb, depth, flags, fx, fy, cx, cy):
    """Rasterise one camera-frame triangle whose vertices are all in front of the near plane."""
    height, width = depth.shape
    u0, v0 = fx * x0 / z0 + cx, fy * y0 / z0 + cy
    u1, v1 = fx * x1 / z1 + cx, fy * y1 / z1 + cy
    u2, v2 = fx * x2 / z2 + cx, fy * y2 / z2 + cy
    area = (u1 - u0) * (v2 - v0) - (v1 - v0) * (u2 - u0)
    if abs(area) < 1e-12:
        return
    c_lo = max(math.ceil(min(u0, u1, u2) - 0.5), 0)
    c_hi = min(math.floor(max(u0, u1, u2) - 0.5), width - 1)
    r_lo = max(math.ceil(min(v0, v1, v2) - 0.5), 0)
    r_hi = min(math.floor(max(v0, v1, v2) - 0.5), height - 1)
    if c_lo > c_hi or r_lo > r_hi:
        return
    inv = 1.0 / area
    iz0, iz1, iz2 = 1.0 / z0, 1.0 / z1, 1.0 / z2
    # barycentric weights are affine in (u, v): w = a + du * u + dv * v
    a0_du, a0_dv = -(v2 - v1) * inv, (u2 - u1) * inv
    a1_du, a1_dv = -(v0 - v2) * inv, (u0 - u2) * inv
    a2_du, a2_dv = -(v1 - v0) * inv, (u1 - u0) * inv
    pu0, pv0 = c_lo + 0.5, r_lo + 0.5
    w0_row = ((u2 - u1) * (pv0 - v1) - (v2 - v1) * (pu0 - u1)) * inv
    w1_row = ((u0 - u2) * (pv0 - v2) - (v0 - v2) * (pu0 - u2)) * inv
    w2_row = ((u1 - u0) * (pv0 - v0) - (v1 - v0) * (pu0 - u0)) * inv
    eps = -1e-7
    for row in range(r_lo, r_hi + 1):
        w0, w1, w2 = w0_row, w1_row, w2_row
        for col in range(c_lo, c_hi + 1):
            if w0 >= eps and w1 >= eps and w2 >= eps:
                z = keep / (w0 * iz0 + w1 * iz1 + w2 * iz2)
                if z < depth[row, col]:
                    depth[row, col] = z
                    rgb[row, col, 0] = r
                    rgb[row, col, 1] = g
                    rgb[row, col, 2] = b
                    flags[row, col] = flag
            w0 += a0_du
            w1 += a1_du
            w2 += a2_du
        w0_row += a0_dv
        w1_row += a1_dv
        w2_row += a2_dv


@njit(cache=True, fastmath=True)
def _clip_fill(v, near, r, g, b, flag, keep, rgb, depth, flags, fx, fy, cx, cy):
    """Clip the camera-frame triangle ``v`` (3, 3) against z = near and rasterise what is left."""
    front = 0
    for k in range(3):
        if v[k, 2] >= near:
            front += 1
    if front == 0:
        return
    if front == 3:
        _fill(
            v[0, 0],
            v[0, 1],
            v[0, 2],
            v[1, 0],
            v[1, 1],
            v[1, 2],
            v[2, 0],
            v[2, 1],
            v[2, 2],
            r,
            g,
            b,
            flag,
            keep,
            rgb,
            depth,
            flags,
            fx,
            fy,
            cx,
            cy,
        )
        return
    # rotate so that the vertices keep their winding: one in front (a) or one behind (c)
    lone = 0
    for k in range(3):
        if (v[k, 2] >= near) == (front == 1):
            lone = k
    a, b_, c = lone, (lone + 1) % 3, (lone + 2) % 3
    # points where edges a-b and a-c cross the near plane
    tb = (near - v[a, 2]) / (v[b_, 2] - v[a, 2])
    tc = (near - v[a, 2]) / (v[c, 2] - v[a, 2])
    abx, aby = v[a, 0] + tb * (v[b_, 0] - v[a, 0]), v[a, 1] + tb * (v[b_, 1] - v[a, 1])
    acx, acy = v[a, 0] + tc * (v[c, 0] - v[a, 0]), v[a, 1] + tc * (v[c, 1] - v[a, 1])
    if front == 1:  # a in front: triangle a, ab, ac
        _fill(
            v[a, 0],
            v[a, 1],
            v[a, 2],
            abx,
            aby,
            near,
            acx,
            acy,
            near,
            r,
            g,
            b,
            flag,
            keep,
            rgb,
            depth,
            flags,
            fx,
            fy,
            cx,
            cy,
        )
    else:  # a behind: quad ab, b, c, ac
        _fill(
            abx,
            aby,
            near,
            v[b_, 0],
            v[b_, 1],
            v[b_, 2],
            v[c, 0],
            v[c, 1],
            v[c, 2],
            r,
            g,
            b,
            flag,
            keep,
            rgb,
            depth,
            flags,
            fx,
            fy,
            cx,
            cy,
        )
        _fill(
            abx,
            aby,
            near,
            v[c, 0],
            v[c, 1],
            v[c, 2],
            acx,
            acy,
            near,
            r,
            g,
            b,
            flag,
            keep,
            rgb,
            depth,
            flags,
            fx,
            fy,
            cx,
            cy,
        )


@njit(cache=True, fastmath=True)
def _visible_disc(dx, dy, cos_y, sin_y, radius, max_range, cos_h, sin_h):
    """Whether a vertical cylinder (centre offset dx, dy from the camera, radius) can be in view."""
    if dx * dx + dy * dy > (max_range + radius) ** 2:
        return False
    fwd = dx * cos_y + dy * sin_y
    left = -dx * sin_y + dy * cos_y
    if fwd < -radius:
        return False
    # signed distances to the two vertical side planes of the frustum (positive outside)
    if left * cos_h - fwd * sin_h > radius:
        return False
    if -left * cos_h - fwd * sin_h > radius:
        return False
    return True


@njit(cache=True, fastmath=True)
def _draw_range(
    tris,
    colours,
    tflags,
    keep,
    lo,
    hi,
    px,
    py,
    pz,
    cos_y,
    sin_y,
    scratch,
    near,
    rgb,
    depth,
    flags,
    fx,
    fy,
    cx,
    cy,
):
    for t in range(lo, hi):
        for k in range(3):
            dx = tris[t, k, 0] - px
            dy = tris[t, k, 1] - py
            scratch[k, 0] = dx * sin_y - dy * cos_y  # right
            scratch[k, 1] = pz - tris[t, k, 2]  # down
            scratch[k, 2] = dx * cos_y + dy * sin_y  # forward
        _clip_fill(
            scratch,
            near,
            colours[t, 0],
            colours[t, 1],
            colours[t, 2],
            tflags[t],
            keep[t],
            rgb,
            depth,
            flags,
            fx,
            fy,
            cx,
            cy,
        )


@njit(cache=True, parallel=True, fastmath=True)
def rasterise(
    poses,  # (n, 4) float64 camera x, y, z [m], yaw [rad] (level)
    skip_actor,  # (n,) int64 actor not drawn in camera i (its own vehicle), -1 none
    intrinsics,  # (6,) float64 fx, fy, cx, cy [px], near [m], max range [m]
    half_fov,  # horizontal half field of view [rad]
    sky_top,  # (3,) float32 colour at the top row
    sky_horizon,  # (3,) float32 colour at the horizon
    grass,  # (3,) float32 ground plane colour
    s_tris,
    s_col,
    s_flags,
    s_keep,  # static triangles, sorted by grid cell: (S, 3, 3), (S, 3), (S,), (S,)
    cell_ptr,  # (C + 1,) int64 CSR of static triangles over the grid's cells
    cell_xy,  # (C, 2) float64 cell centres [m]
    cell_reach,  # (C,) float64 radius around the cell centre holding all its triangles [m]
    grid,  # (5,) float64 x0, y0, cell size [m], nx, ny
    d_tris,
    d_col,
    d_flags,
    d_keep,  # dynamic (actor) triangles, grouped by actor
    actor_ptr,  # (A + 1,) int64 CSR of dynamic triangles over actors
    actor_xy,  # (A, 2) float64 actor centres [m]
    actor_reach,  # (A,) float64 [m]
    rgb,  # out (n, H, W, 3) float32
    depth,  # out (n, H, W) float32 [m]
    flags,  # out (n, H, W) uint8
):
    n, height, width = depth.shape
    fx, fy, cx, cy, near, max_range = intrinsics
    cos_h, sin_h = math.cos(half_fov), math.sin(half_fov)
    x0, y0, cell, nx, ny = grid[0], grid[1], grid[2], int(grid[3]), int(grid[4])
    for i in prange(n):
        px, py, pz, yaw = poses[i, 0], poses[i, 1], poses[i, 2], poses[i, 3]
        cos_y, sin_y = math.cos(yaw), math.sin(yaw)
        img, dep, flg = rgb[i], depth[i], flags[i]
        # background: sky above the horizon, the ground plane z = 0 below it
        for row in range(height):
            dv = row + 0.5 - cy
            if dv > 0.0:
                z_ground = np.float32(pz * fy / dv)
                for col in range(width):
                    dep[row, col] = z_ground
                    img[row, col, :] = grass
                    flg[row, col] = FLAG_GRASS
            else:
                t = min(-dv / cy, 1.0) ** 0.6
                for col in range(width):
                    dep[row, col] = np.inf
                    for ch in range(3):
                        img[row, col, ch] = sky_horizon[ch] + t * (sky_top[ch] - sky_horizon[ch])
                    flg[row, col] = FLAG_SKY
        scratch = np.empty((3, 3))
        # static triangles of the grid cells in range and in the horizontal field of view
        reach_cells = int(max_range / cell) + 2
        gx, gy = int((px - x0) / cell), int((py - y0) / cell)
        for jx in range(max(gx - reach_cells, 0), min(gx + reach_cells + 1, nx)):
            for jy in range(max(gy - reach_cells, 0), min(gy + reach_cells + 1, ny)):
                c = jx * ny + jy
                lo, hi = cell_ptr[c], cell_ptr[c + 1]
                if lo == hi:
                    continue
                dx, dy = cell_xy[c, 0] - px, cell_xy[c, 1] - py
                if not _visible_disc(dx, dy, cos_y, sin_y, cell_reach[c], max_range, cos_h, sin_h):
                    continue
                _draw_range(
                    s_tris,
                    s_col,
                    s_flags,
                    s_keep,
                    lo,
                    hi,
                    px,
                    py,
                    pz,
                    cos_y,
                    sin_y,
                    scratch,
                    near,
                    img,
                    dep,
                    flg,
                    fx,
                    fy,
                    cx,
                    cy,
                )
        for a in range(actor_ptr.shape[0] - 1):
            if a == skip_actor[i]:
                continue
            dx, dy = actor_xy[a, 0] - px, actor_xy[a, 1] - py
            if not _visible_disc(dx, dy, cos_y, sin_y, actor_reach[a], max_range, cos_h, sin_h):
                continue
            _draw_range(
                d_tris,
                d_col,
                d_flags,
                d_keep,
                actor_ptr[a],
                actor_ptr[a + 1],
                px,
                py,
                pz,
                cos_y,
                sin_y,
                scratch,
                near,
                img,
                dep,
                flg,
                fx,
                fy,
                cx,
                cy,
            )


@njit(cache=True, fastmath=True)
def _hash01(seed, k):
    """A deterministic pseudo-random number in [0, 1) from two integers (splitmix-style)."""
    h = (seed * 0x9E3779B1 + k * 0x85EBCA77 + 0x165667B1) & 0xFFFFFFFF
    h ^= h >> 15
    h = (h * 0x2C1B3C6D) & 0xFFFFFFFF
    h ^= h >> 12
    h = (h * 0x297A2D39) & 0xFFFFFFFF
    h ^= h >> 15
    return h / 4294967296.0


@njit(cache=True, parallel=True, fastmath=True)
def shade(
    rgb,  # (n, H, W, 3) float32 flat colours from `rasterise`
    depth,  # (n, H, W) float32 [m]
    flags,  # (n, H, W) uint8
    ray_len,  # (H, W) float32 length of the camera ray per unit z
    light,  # (3,) float32 ambient light (brightness x tint) on lit surfaces
    fog,  # (3,) float32 fog / haze colour
    params,  # (8,) float64: extinction [1/m], sky distance [m], wet, head_strength, head_range [m],
    #          rain, camera height [m], lamp forward [m]
    intrinsics,  # (4,) float64 fx, fy, cx, cy
    seeds,  # (n,) int64 per-camera seed of the rain streaks
    out,  # out (n, H, W, 3) uint8
):
    n, height, width = depth.shape
    beta, sky_dist, wet, head, head_range, rain, cam_h, lamp_fwd = params
    fx, fy, cx, cy = intrinsics
    lamp_down = cam_h - 0.7  # headlights 0.7 m above the road
    for i in prange(n):
        lit = np.empty((height, width, 3), np.float32)
        for row in range(height):
            for col in range(width):
                f = flags[i, row, col]
                z = depth[i, row, col]
                c0, c1, c2 = rgb[i, row, col, 0], rgb[i, row, col, 1], rgb[i, row, col, 2]
                if f & FLAG_SKY:
                    dist = sky_dist
                else:
                    dist = z * ray_len[row, col]
                    if f & FLAG_ROAD and wet > 0.0:  # wet asphalt: darker, with a sheen of the sky
                        c0 = c0 * (1.0 - 0.45 * wet) + 0.12 * wet * fog[0]
                        c1 = c1 * (1.0 - 0.45 * wet) + 0.12 * wet * fog[1]
                        c2 = c2 * (1.0 - 0.45 * wet) + 0.12 * wet * fog[2]
                    elif f & FLAG_GRASS and wet > 0.0:
                        c0, c1, c2 = c0 * (1.0 - 0.2 * wet), c1 * (1.0 - 0.2 * wet), c2 * (1.0 - 0.2 * wet)
                    if not f & FLAG_EMISSIVE:
                        gain = 0.0
                        if head > 0.0:  # the ego's low beams: a cone from the front bumper
                            x = (col + 0.5 - cx) / fx * z
                            y = (row + 0.5 - cy) / fy * z - lamp_down
                            fwd = z - lamp_fwd
                            if fwd > 0.5:
                                h_ang = x / fwd
                                v_ang = y / fwd  # > 0 below the lamps
                                beam = math.exp(-((h_ang / 0.7) ** 2))
                                if v_ang < 0.0:  # low-beam cut-off above the lamp height
                                    beam *= math.exp(-((v_ang / 0.05) ** 2))
                                d = math.sqrt(x * x + y * y + fwd * fwd)
                                gain = head * beam / (1.0 + (d / head_range) ** 2)
                        c0 = c0 * (light[0] + gain)
                        c1 = c1 * (light[1] + gain * 0.97)
                        c2 = c2 * (light[2] + gain * 0.88)
                t = math.exp(-beta * dist)
                lit[row, col, 0] = c0 * t + fog[0] * (1.0 - t)
                lit[row, col, 1] = c1 * t + fog[1] * (1.0 - t)
                lit[row, col, 2] = c2 * t + fog[2] * (1.0 - t)
        if rain > 0.0:
            _rain(lit, rain, seeds[i])
        for row in range(height):
            for col in range(width):
                for ch in range(3):
                    v = lit[row, col, ch] * 255.0 + 0.5
                    out[i, row, col, ch] = np.uint8(min(max(v, 0.0), 255.0))


@njit(cache=True, fastmath=True)
def _rain(img, rain, seed):
    """Blur (water on the lens) and bright slanted streaks (falling drops), both scaled by ``rain``."""
    height, width, _ = img.shape
    src = img.copy()
    mix = 0.6 * rain
    for row in range(height):
        for col in range(width):
            for ch in range(3):
                acc = 0.0
                cnt = 0
                for dr in range(-1, 2):
                    for dc in range(-1, 2):
                        rr, cc = row + dr, col + dc
                        if 0 <= rr < height and 0 <= cc < width:
                            acc += src[rr, cc, ch]
                            cnt += 1
                img[row, col, ch] = (1.0 - mix) * src[row, col, ch] + mix * acc / cnt
    streaks = int(rain * width * height / 300)
    length = max(height // 10, 4)
    for k in range(streaks):
        c0 = _hash01(seed, 3 * k) * width
        r0 = _hash01(seed, 3 * k + 1) * height
        alpha = 0.12 + 0.18 * _hash01(seed, 3 * k + 2)
        for s in range(length):
            row, col = int(r0 + s), int(c0 + 0.25 * s)
            if 0 <= row < height and 0 <= col < width:
                for ch in range(3):
                    img[row, col, ch] += alpha * (0.85 - img[row, col, ch])
