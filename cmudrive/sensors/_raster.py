"""Numba kernels of the front camera: a z-buffered triangle rasteriser and the per-pixel weather / light
pass, run for all cameras of a tick in one parallel call. See :mod:`cmudrive.sensors.camera` for the
model and the conventions.

Camera frame (OpenCV): x right, y down, z forward [m]; pixel (row r, col c) has its centre at image
coordinates (u, v) = (c + 0.5, r + 0.5), u = fx x / z + cx, v = fy y / z + cy. The depth buffer holds z
(distance along the optical axis) [m], +inf for sky. Triangles carry a ``keep`` factor (1 - depth bias):
the z-test compares ``z * keep``, so coplanar layers on the ground (road over grass, markings over road)
win by layer instead of z-fighting; the stored depth is that biased value (at most 0.3 % short).

Each camera is rasterised and shaded in one pass of the parallel loop, while its buffers are in cache.
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
def _fill(poly, i0, i1, i2, colour, flag, keep, img, dep, flg, lens):
    """Rasterise triangle (i0, i1, i2) of the camera-frame polygon ``poly`` (k, 3), all in front of the
    near plane. ``lens`` = (fx, fy, cx, cy) [px]."""
    fx, fy, cx, cy = lens
    height, width = dep.shape
    z0, z1, z2 = poly[i0, 2], poly[i1, 2], poly[i2, 2]
    u0, v0 = fx * poly[i0, 0] / z0 + cx, fy * poly[i0, 1] / z0 + cy
    u1, v1 = fx * poly[i1, 0] / z1 + cx, fy * poly[i1, 1] / z1 + cy
    u2, v2 = fx * poly[i2, 0] / z2 + cx, fy * poly[i2, 1] / z2 + cy
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
    # barycentric weights are affine in the pixel position: w(c + 1) = w(c) + d_du, w(r + 1) = w(r) + d_dv
    d0_du, d0_dv = -(v2 - v1) * inv, (u2 - u1) * inv
    d1_du, d1_dv = -(v0 - v2) * inv, (u0 - u2) * inv
    d2_du, d2_dv = -(v1 - v0) * inv, (u1 - u0) * inv
    pu, pv = c_lo + 0.5, r_lo + 0.5
    w0_row = ((u2 - u1) * (pv - v1) - (v2 - v1) * (pu - u1)) * inv
    w1_row = ((u0 - u2) * (pv - v2) - (v0 - v2) * (pu - u2)) * inv
    w2_row = ((u1 - u0) * (pv - v0) - (v1 - v0) * (pu - u0)) * inv
    eps = -1e-7  # closes hairline cracks between triangles sharing an edge
    for row in range(r_lo, r_hi + 1):
        # the columns where all three weights are >= eps: each is affine in the column, so solve
        lo_f, hi_f = float(c_lo), float(c_hi)
        lo_f, hi_f = _span(w0_row, d0_du, eps, c_lo, lo_f, hi_f)
        lo_f, hi_f = _span(w1_row, d1_du, eps, c_lo, lo_f, hi_f)
        lo_f, hi_f = _span(w2_row, d2_du, eps, c_lo, lo_f, hi_f)
        if lo_f <= hi_f:
            first, last = max(math.ceil(lo_f), c_lo), min(math.floor(hi_f), c_hi)
            k = first - c_lo
            w0, w1, w2 = w0_row + k * d0_du, w1_row + k * d1_du, w2_row + k * d2_du
            for col in range(first, last + 1):
                if w0 >= eps and w1 >= eps and w2 >= eps:  # guards the rounding at the span's ends
                    z = keep / (w0 * iz0 + w1 * iz1 + w2 * iz2)  # perspective-correct depth
                    if z < dep[row, col]:
                        dep[row, col] = z
                        img[row, col, 0] = colour[0]
                        img[row, col, 1] = colour[1]
                        img[row, col, 2] = colour[2]
                        flg[row, col] = flag
                w0 += d0_du
                w1 += d1_du
                w2 += d2_du
        w0_row += d0_dv
        w1_row += d1_dv
        w2_row += d2_dv


@njit(cache=True, fastmath=True)
def _span(w, d, eps, c_lo, lo, hi):
    """Narrow the column interval [lo, hi] to where w + d (col - c_lo) >= eps (with a pixel of slack)."""
    if d > 1e-12:
        lo = max(lo, c_lo + (eps - w) / d - 1.0)
    elif d < -1e-12:
        hi = min(hi, c_lo + (eps - w) / d + 1.0)
    elif w < eps:
        hi = lo - 1.0
    return lo, hi


@njit(cache=True, fastmath=True)
def _clip(tri, near, poly):
    """Clip the camera-frame triangle ``tri`` (3, 3) to z >= near into ``poly`` (4, 3); vertex count."""
    k = 0
    for a in range(3):
        b = (a + 1) % 3
        za, zb = tri[a, 2], tri[b, 2]
        if za >= near:
            poly[k, :] = tri[a, :]
            k += 1
        if (za >= near) != (zb >= near):  # the edge crosses the near plane
            t = (near - za) / (zb - za)
            for ch in range(3):
                poly[k, ch] = tri[a, ch] + t * (tri[b, ch] - tri[a, ch])
            poly[k, 2] = near
            k += 1
    return k


@njit(cache=True, fastmath=True)
def _visible_disc(dx, dy, cos_y, sin_y, radius, max_range, cos_h, sin_h):
    """Whether a vertical cylinder (centre offset dx, dy [m] from the camera, radius [m]) can be in view."""
    if dx * dx + dy * dy > (max_range + radius) ** 2:
        return False
    fwd = dx * cos_y + dy * sin_y
    left = -dx * sin_y + dy * cos_y
    if fwd < -radius:
        return False
    # signed distances to the two vertical side planes of the frustum (positive outside)
    return left * cos_h - fwd * sin_h <= radius and -left * cos_h - fwd * sin_h <= radius


@njit(cache=True, fastmath=True)
def _draw(tris, colours, tflags, keep, lo, hi, pose, near, img, dep, flg, lens, tri, poly):
    """Transform triangles lo..hi into the camera frame of ``pose`` (x, y, z, cos yaw, sin yaw), clip
    and rasterise them; ``tri`` (3, 3) and ``poly`` (4, 3) are scratch."""
    px, py, pz, cos_y, sin_y = pose
    for t in range(lo, hi):
        behind = 0
        for k in range(3):
            dx = tris[t, k, 0] - px
            dy = tris[t, k, 1] - py
            tri[k, 0] = dx * sin_y - dy * cos_y  # right
            tri[k, 1] = pz - tris[t, k, 2]  # down
            tri[k, 2] = dx * cos_y + dy * sin_y  # forward
            if tri[k, 2] < near:
                behind += 1
        if behind == 3:
            continue
        count = 3
        if behind:
            count = _clip(tri, near, poly)
        else:
            poly[:3, :] = tri
        for j in range(1, count - 1):  # fan
            _fill(poly, 0, j, j + 1, colours[t], tflags[t], keep[t], img, dep, flg, lens)


@njit(cache=True, fastmath=True)
def _background(img, dep, flg, cam_height, lens, sky_top, sky_horizon, grass):
    """Sky above the horizon (a vertical gradient), the ground plane z = 0 below it."""
    height, width = dep.shape
    fy, cy = lens[1], lens[3]
    for row in range(height):
        dv = row + 0.5 - cy
        if dv > 0.0:
            z, flag = np.float32(cam_height * fy / dv), FLAG_GRASS
            c0, c1, c2 = grass[0], grass[1], grass[2]
        else:
            t = min(-dv / cy, 1.0) ** 0.6
            z, flag = np.float32(np.inf), FLAG_SKY
            c0 = sky_horizon[0] + t * (sky_top[0] - sky_horizon[0])
            c1 = sky_horizon[1] + t * (sky_top[1] - sky_horizon[1])
            c2 = sky_horizon[2] + t * (sky_top[2] - sky_horizon[2])
        for col in range(width):
            dep[row, col] = z
            img[row, col, 0] = c0
            img[row, col, 1] = c1
            img[row, col, 2] = c2
            flg[row, col] = flag


@njit(cache=True, parallel=True, fastmath=True)
def render_batch(
    poses,  # (n, 4) float64 camera x, y, z [m], yaw [rad] (level)
    skip_actor,  # (n,) int64 actor not drawn in camera i (its own vehicle), -1 none
    lens,  # (4,) float64 fx, fy, cx, cy [px]
    clip,  # (3,) float64 near [m], max range [m], horizontal half field of view [rad]
    static,  # static triangles sorted by grid cell: xyz (S, 3, 3), colour (S, 3), flags (S,), keep (S,)
    cells,  # cell_ptr (C + 1,) CSR over the grid's cells, cell centres (C, 2) [m], reach (C,) [m]
    grid,  # (5,) float64 x0, y0, cell size [m], nx, ny
    dynamic,  # actor triangles grouped by actor: xyz, colour, flags, keep
    actors,  # actor_ptr (A + 1,) CSR over actors, centres (A, 2) [m], reach (A,) [m]
    look,  # sky_top, sky_horizon (= fog colour), grass, light (ambient x tint): (3,) float32 each
    params,  # (8,) float64 weather numbers, see `_shade`
    ray_len,  # (H, W) float32 length of the camera ray per unit z
    seeds,  # (n,) int64 per-camera seed of the rain streaks
    out,  # out (n, H, W, 3) uint8
    depth,  # out (n, H, W) float32 [m]
):
    n, height, width = depth.shape
    near, max_range, half_fov = clip
    cos_h, sin_h = math.cos(half_fov), math.sin(half_fov)
    s_xyz, s_col, s_flags, s_keep = static
    cell_ptr, cell_xy, cell_reach = cells
    d_xyz, d_col, d_flags, d_keep = dynamic
    actor_ptr, actor_xy, actor_reach = actors
    x0, y0, cell, nx, ny = grid[0], grid[1], grid[2], int(grid[3]), int(grid[4])
    reach_cells = int(max_range / cell) + 2
    for i in prange(n):
        img = np.empty((height, width, 3), np.float32)
        flg = np.empty((height, width), np.uint8)
        dep = depth[i]
        tri = np.empty((3, 3))
        poly = np.empty((4, 3))
        px, py, pz, yaw = poses[i, 0], poses[i, 1], poses[i, 2], poses[i, 3]
        cos_y, sin_y = math.cos(yaw), math.sin(yaw)
        pose = (px, py, pz, cos_y, sin_y)
        _background(img, dep, flg, pz, lens, look[0], look[1], look[2])
        # static triangles of the grid cells in range and in the horizontal field of view
        gx, gy = int((px - x0) / cell), int((py - y0) / cell)
        for jx in range(max(gx - reach_cells, 0), min(gx + reach_cells + 1, nx)):
            for jy in range(max(gy - reach_cells, 0), min(gy + reach_cells + 1, ny)):
                c = jx * ny + jy
                lo, hi = cell_ptr[c], cell_ptr[c + 1]
                if lo == hi:
                    continue
                dx, dy = cell_xy[c, 0] - px, cell_xy[c, 1] - py
                if _visible_disc(dx, dy, cos_y, sin_y, cell_reach[c], max_range, cos_h, sin_h):
                    _draw(s_xyz, s_col, s_flags, s_keep, lo, hi, pose, near, img, dep, flg, lens, tri, poly)
        for a in range(actor_ptr.shape[0] - 1):
            if a == skip_actor[i]:
                continue
            dx, dy = actor_xy[a, 0] - px, actor_xy[a, 1] - py
            if _visible_disc(dx, dy, cos_y, sin_y, actor_reach[a], max_range, cos_h, sin_h):
                lo, hi = actor_ptr[a], actor_ptr[a + 1]
                _draw(d_xyz, d_col, d_flags, d_keep, lo, hi, pose, near, img, dep, flg, lens, tri, poly)
        _shade(img, dep, flg, ray_len, look[3], look[1], params, lens)
        if params[5] > 0.0:
            _rain(img, params[5], seeds[i])
        _to_uint8(img, out[i])


@njit(cache=True, fastmath=True)
def _to_uint8(img, out):
    """[0, 1] floats to 0..255, rounded and clipped."""
    flat_in, flat_out = img.reshape(-1), out.reshape(-1)
    scale, half, top = np.float32(255.0), np.float32(0.5), np.float32(255.0)
    for k in range(flat_in.shape[0]):
        flat_out[k] = np.uint8(min(max(flat_in[k] * scale + half, np.float32(0.0)), top))


@njit(cache=True, fastmath=True)
def _shade(img, dep, flg, ray_len, light, fog, params, lens):
    """Light, wetness and haze, in place. ``params``: extinction [1/m], sky distance [m], wetness [0..1],
    headlight strength, headlight range [m], rain [0..1], camera height [m], camera to the lamps [m]."""
    f32 = np.float32
    beta, sky_dist, wet, head, head_range = f32(params[0]), f32(params[1]), params[2], params[3], params[4]
    lamp_down, lamp_fwd = params[6] - 0.7, params[7]  # headlights 0.7 m above the road
    fx, fy, cx, cy = lens
    road_keep, road_sheen, grass_keep = f32(1.0 - 0.45 * wet), f32(0.12 * wet), f32(1.0 - 0.2 * wet)
    one = f32(1.0)
    height, width = dep.shape
    for row in range(height):
        for col in range(width):
            f = flg[row, col]
            z = dep[row, col]
            c0, c1, c2 = img[row, col, 0], img[row, col, 1], img[row, col, 2]
            if f & FLAG_SKY:
                dist = sky_dist
            else:
                dist = z * ray_len[row, col]
                if f & FLAG_ROAD:  # wet asphalt: darker, with a sheen of the sky
                    c0 = c0 * road_keep + road_sheen * fog[0]
                    c1 = c1 * road_keep + road_sheen * fog[1]
                    c2 = c2 * road_keep + road_sheen * fog[2]
                elif f & FLAG_GRASS:
                    c0, c1, c2 = c0 * grass_keep, c1 * grass_keep, c2 * grass_keep
                if not f & FLAG_EMISSIVE:
                    gain = f32(0.0)
                    if head > 0.0:  # the ego's low beams: a cone from the front bumper
                        x = (col + 0.5 - cx) / fx * z
                        y = (row + 0.5 - cy) / fy * z - lamp_down
                        fwd = z - lamp_fwd
                        if fwd > 0.5:
                            beam = math.exp(-((x / fwd / 0.7) ** 2))
                            if y < 0.0:  # low-beam cut-off above the lamp height
                                beam *= math.exp(-((y / fwd / 0.05) ** 2))
                            d = math.sqrt(x * x + y * y + fwd * fwd)
                            gain = f32(head * beam / (1.0 + (d / head_range) ** 2))
                    c0 = c0 * (light[0] + gain)
                    c1 = c1 * (light[1] + gain * f32(0.97))
                    c2 = c2 * (light[2] + gain * f32(0.88))
            t = math.exp(-beta * dist)
            img[row, col, 0] = c0 * t + fog[0] * (one - t)
            img[row, col, 1] = c1 * t + fog[1] * (one - t)
            img[row, col, 2] = c2 * t + fog[2] * (one - t)


@njit(cache=True, fastmath=True)
def _hash01(seed, k):
    """A deterministic pseudo-random number in [0, 1) from two integers (a 32-bit integer hash)."""
    h = (seed * 0x9E3779B1 + k * 0x85EBCA77 + 0x165667B1) & 0xFFFFFFFF
    h ^= h >> 15
    h = (h * 0x2C1B3C6D) & 0xFFFFFFFF
    h ^= h >> 12
    h = (h * 0x297A2D39) & 0xFFFFFFFF
    h ^= h >> 15
    return h / 4294967296.0


@njit(cache=True, fastmath=True)
def _rain(img, rain, seed):
    """Blur (water on the lens) and bright slanted streaks (falling drops), both scaled by ``rain``."""
    height, width, _ = img.shape
    flat = img.reshape(height, width * 3)  # a view: channels interleaved along each row
    src = flat.copy()
    tmp = flat.copy()
    mix = np.float32(0.6 * rain)
    third = np.float32(1.0 / 3.0)
    for row in range(height):  # 3 x 3 box blur, separable; the outermost pixels stay sharp
        for k in range(3, 3 * width - 3):
            tmp[row, k] = (src[row, k - 3] + src[row, k] + src[row, k + 3]) * third
    for row in range(1, height - 1):
        for k in range(3 * width):
            blur = (tmp[row - 1, k] + tmp[row, k] + tmp[row + 1, k]) * third
            flat[row, k] = src[row, k] + mix * (blur - src[row, k])
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
