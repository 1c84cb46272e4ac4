"""A straightforward numpy reference of every stage of the matcher.

Written from the definitions (the paper's Eqs. 7-16 and the conventions in
csrc/cellctl_core.h), not from the C code, and slow on purpose: clarity over
speed.  Integer arithmetic throughout, so the C core must match it exactly.
"""

from __future__ import annotations

import numpy as np

INVALID = -32768
LUT = 64


def box3_sum(img: np.ndarray) -> np.ndarray:
    """Sum of each pixel's 3x3 neighbourhood, borders replicated."""
    h, w = img.shape
    pad = np.pad(img.astype(np.int64), 1, mode="edge")
    return sum(pad[1 + dy : 1 + dy + h, 1 + dx : 1 + dx + w] for dy in (-1, 0, 1) for dx in (-1, 0, 1))


def census(img: np.ndarray, cw: int, ch: int, smooth: int = 0, threshold: int = 0) -> np.ndarray:
    """Bit i set when the centre >= the i-th neighbour (raster order), borders replicated;
    with smooth = 1 the compared values are the pixels' 3x3 sums.  Ternary with threshold t > 0:
    neighbour i sets bit 2i when centre - neighbour >= t and bit 2i+1 when neighbour - centre >= t."""
    h, w = img.shape
    rx, ry = cw // 2, ch // 2
    img = box3_sum(img) if smooth else img.astype(np.int64)
    pad = np.pad(img, ((ry, ry), (rx, rx)), mode="edge")
    out = np.zeros((h, w), np.uint64)
    bit = 0
    for dy in range(-ry, ry + 1):
        for dx in range(-rx, rx + 1):
            if dx == 0 and dy == 0:
                continue
            neighbour = pad[ry + dy : ry + dy + h, rx + dx : rx + dx + w]
            if threshold == 0:
                out |= (img >= neighbour).astype(np.uint64) << np.uint64(bit)
                bit += 1
                continue
            out |= (img - neighbour >= threshold).astype(np.uint64) << np.uint64(bit)
            out |= (neighbour - img >= threshold).astype(np.uint64) << np.uint64(bit + 1)
            bit += 2
    return out


def bt_bounds(img: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Min and max over the pixel and its half-pixel neighbours (floor of the mean)."""
    i = img.astype(np.int64)
    left = np.concatenate([i[:, :1], i[:, :-1]], axis=1)
    right = np.concatenate([i[:, 1:], i[:, -1:]], axis=1)
    a, b = (i + left) >> 1, (i + right) >> 1
    return np.minimum(np.minimum(i, a), b), np.maximum(np.maximum(i, a), b)


def bt_image(img: np.ndarray, cap: int) -> np.ndarray:
    """The image BT compares: the grey image (cap 0) or its horizontal Sobel clipped to [-cap, cap], + cap."""
    if cap == 0:
        return img
    h, w = img.shape
    pad = np.pad(img.astype(np.int64), 1, mode="edge")
    dx = pad[:, 2:] - pad[:, :-2]  # I(x+1) - I(x-1), rows -1..h
    sobel = dx[:-2] + 2 * dx[1:-1] + dx[2:]
    return (np.clip(sobel, -cap, cap) + cap).astype(np.uint8)


def rho_table(lam: float, scale: int) -> np.ndarray:
    c = np.arange(LUT, dtype=np.float64)
    return np.floor(scale * (1.0 - np.exp(-c / np.float64(np.float32(lam)))) + 0.5).astype(np.int64)


def cost_volume(left, right, p) -> np.ndarray:
    h, w = left.shape
    D, dmin = p["num_disparities"], p["min_disparity"]
    cw, ch = p["census_window"]
    tc = rho_table(p["lambda_census"], p["cost_scale"]) if p["cost"] != "bt" else np.zeros(LUT, np.int64)
    tb = rho_table(p["lambda_bt"], p["cost_scale"]) if p["cost"] != "census" else np.zeros(LUT, np.int64)
    cmax = tc[-1] + tb[-1]
    smooth = p["census_smooth"]
    t = p["census_threshold"]
    cl = census(left, cw, ch, smooth, t) if p["cost"] != "bt" else np.zeros((h, w), np.uint64)
    cr = census(right, cw, ch, smooth, t) if p["cost"] != "bt" else np.zeros((h, w), np.uint64)
    left, right = bt_image(left, p["bt_prefilter"]), bt_image(right, p["bt_prefilter"])
    il, ir = left.astype(np.int64), right.astype(np.int64)
    lmin, lmax = bt_bounds(left)
    rmin, rmax = bt_bounds(right)
    vol = np.full((h, w, D), cmax, np.int64)
    x = np.arange(w)
    for k in range(D):
        xr = x - (dmin + k)
        ok = (xr >= 0) & (xr < w)
        xs, xrs = x[ok], xr[ok]
        ham = np.bitwise_count(cl[:, xs] ^ cr[:, xrs]).astype(np.int64)
        lr = np.maximum(0, np.maximum(il[:, xs] - rmax[:, xrs], rmin[:, xrs] - il[:, xs]))
        rl = np.maximum(0, np.maximum(ir[:, xrs] - lmax[:, xs], lmin[:, xs] - ir[:, xrs]))
        bt = np.minimum(np.minimum(lr, rl), LUT - 1)
        vol[:, xs, k] = tc[ham] + tb[bt]
    return vol


def _p2(p, cur, prev):
    if p["p2_gamma"] == 0:
        return np.full(cur.shape, p["p2"], np.int64)
    g = p["p2_gamma"]
    v = p["p2"] * g // (g + np.abs(cur.astype(np.int64) - prev.astype(np.int64)))
    return np.maximum(v, p["p1"])


def _step(cost, prev, p2, p1):
    """L = C + min(Lp(d), Lp(d+-1) + P1, min Lp + P2) - min Lp, vectorised over pixels."""
    big = np.int64(1) << 40
    pm = prev.min(axis=1, keepdims=True)
    lo = np.concatenate([np.full((prev.shape[0], 1), big), prev[:, :-1]], axis=1) + p1
    hi = np.concatenate([prev[:, 1:], np.full((prev.shape[0], 1), big)], axis=1) + p1
    m = np.minimum(np.minimum(prev, lo), np.minimum(hi, pm + p2[:, None]))
    return cost + m - pm


def path(C, img, dy, dx, p):
    """Path costs L_r for direction r = (dy, dx): the previous pixel is (y - dy, x - dx)."""
    h, w, _ = C.shape
    L = np.zeros_like(C)
    if dy != 0:
        rows = range(h) if dy > 0 else range(h - 1, -1, -1)
        for i, y in enumerate(rows):
            if i == 0:
                L[y] = C[y]
                continue
            py, xs = y - dy, np.arange(w)
            px = xs - dx
            ok = (px >= 0) & (px < w)
            L[y, ~ok] = C[y, ~ok]
            L[y, ok] = _step(C[y, ok], L[py, px[ok]], _p2(p, img[y, ok], img[py, px[ok]]), p["p1"])
    else:
        cols = range(w) if dx > 0 else range(w - 1, -1, -1)
        for i, x in enumerate(cols):
            if i == 0:
                L[:, x] = C[:, x]
                continue
            L[:, x] = _step(C[:, x], L[:, x - dx], _p2(p, img[:, x], img[:, x - dx]), p["p1"])
    return L


DIRECTIONS_4 = [(0, 1), (0, -1), (1, 0), (-1, 0)]
DIRECTIONS_8 = DIRECTIONS_4 + [(1, 1), (1, -1), (-1, 1), (-1, -1)]


def aggregate(left, right, p):
    C = cost_volume(left, right, p)
    dirs = DIRECTIONS_8 if p["paths"] == 8 else DIRECTIONS_4
    return sum(path(C, left, dy, dx, p) for dy, dx in dirs)


def select(S, p):
    h, w, D = S.shape
    dmin = p["min_disparity"]
    k = S.argmin(axis=2)
    left = (dmin + k) * 16
    unique = np.ones((h, w), bool)
    if p["uniqueness"]:
        for y in range(h):
            for x in range(w):
                far = [int(S[y, x, j]) for j in range(D) if abs(j - k[y, x]) > 1]
                second = min(far) if far else 0xFFFF
                unique[y, x] = second * (100 - p["uniqueness"]) >= int(S[y, x, k[y, x]]) * 100
    if p["subpixel"]:
        for y in range(h):
            for x in range(w):
                kk = k[y, x]
                if 0 < kk < D - 1:
                    a, b, c = int(S[y, x, kk - 1]), int(S[y, x, kk + 1]), int(S[y, x, kk])
                    denom2 = max(a + b - 2 * c, 1)
                    num = (a - b) * 16 + denom2
                    left[y, x] += int(num / (denom2 * 2))  # C division truncates towards zero
    left[~unique] = INVALID
    right = np.full((h, w), INVALID, np.int64)
    for y in range(h):
        for xr in range(w):
            ks = [kk for kk in range(D) if 0 <= xr + dmin + kk < w]
            if ks:
                costs = [S[y, xr + dmin + kk, kk] for kk in ks]
                right[y, xr] = (dmin + ks[int(np.argmin(costs))]) * 16
    return left, right


def _border_occlusion(row, w):
    """Invalidate pixels whose match, judged by the kept disparity on their inner side, is outside."""
    for xs, outside in (
        (range(w - 1, -1, -1), lambda x, d: x - (d + 8) // 16 < 0),
        (range(w), lambda x, d: x - (d + 8) // 16 >= w),
    ):
        ref = None
        for x in xs:
            if row[x] == INVALID:
                continue
            if ref is not None and outside(x, ref):
                row[x] = INVALID
            else:
                ref = int(row[x])


def _rounded_div(a: int, b: int) -> int:
    """a / b rounded to the nearest integer, halves up (b > 0)."""
    return (2 * a + b) // (2 * b)


def border_strips(checked, y, p) -> dict[int, int]:
    """Line extrapolation of the border-occluded ends of row y: {x: fixed-point disparity}.

    Left strip: x < first kept pixel and x < largest disparity; right strip: x > last kept pixel and
    x >= width + min_disparity.  The line d = a + b u (u = distance from the strip's edge pixel, inward)
    is the least-squares fit to the kept pixels with 0 <= u < border_fit in rows y-2..y+2 that lie
    within 2 px of the edge pixel's value; b rounded to 1/(16*256) px per px and clamped to 1/4 px per px,
    a to 1/(16*256) px, the values to 1/16 px and then into the disparity range.  No strip is written
    when fewer than border_fit pixels qualify or all share one u."""
    h, w = checked.shape
    kept = np.flatnonzero(checked[y] != INVALID)
    if len(kept) == 0:
        return {}
    dmin, dmax = p["min_disparity"], p["min_disparity"] + p["num_disparities"] - 1
    K, out = p["border_fit"], {}
    for edge, side, xs in (
        (kept[0], 1, range(0, min(kept[0], dmax))),
        (kept[-1], -1, range(max(kept[-1] + 1, w + dmin), w)),
    ):
        if len(xs) == 0:
            continue
        d0 = int(checked[y, edge])
        pts = [
            (u, int(checked[yy, edge + side * u]))
            for yy in range(max(0, y - 2), min(h, y + 3))
            for u in range(K)
            if 0 <= edge + side * u < w
            and checked[yy, edge + side * u] != INVALID
            and abs(int(checked[yy, edge + side * u]) - d0) <= 32
        ]
        n = len(pts)
        su, suu = sum(u for u, _ in pts), sum(u * u for u, _ in pts)
        sv, suv = sum(v for _, v in pts), sum(u * v for u, v in pts)
        den = n * suu - su * su
        if n < K or den <= 0:
            continue
        b = min(max(_rounded_div(256 * (n * suv - su * sv), den), -1024), 1024)
        a = _rounded_div(256 * sv - b * su, n)
        for x in xs:
            out[x] = min(max(_rounded_div(a + b * side * (x - edge), 256), dmin * 16), dmax * 16)
    return out


def wm_tables(sigma_colour: float, sigma_space: float) -> tuple[np.ndarray, np.ndarray]:
    """round(256 exp(-x / sigma)) by summed colour difference (0..765) and by squared distance (0..450)."""

    def weight(x, sigma):
        return np.floor(256.0 * np.exp(-x / np.float64(np.float32(sigma))) + 0.5).astype(np.int64)

    return weight(np.arange(766, dtype=np.float64), sigma_colour), weight(np.sqrt(np.arange(451.0)), sigma_space)


def _level(v, p):
    """Whole-pixel level of a fixed-point disparity inside the range, None if invalid."""
    if v == INVALID:
        return None
    return min(max((int(v) + 8) // 16 - p["min_disparity"], 0), p["num_disparities"] - 1)


def weighted_median_at(m, guide, y, x, r, p):
    """Colour-weighted median of map m at (y, x): the level with half the weight, the centre's own
    value when it lies on that level, else the rounded weighted mean of the votes on it."""
    if m[y, x] == INVALID:
        return INVALID
    colour, space = wm_tables(p["wm_sigma_colour"], p["wm_sigma_space"])
    g = guide.astype(np.int64)
    if g.ndim == 2:
        g = np.repeat(g[:, :, None], 3, axis=2)  # grey counts as three equal channels
    h, w = m.shape
    weights, values = {}, {}
    for yy in range(max(0, y - r), min(h, y + r + 1)):
        for xx in range(max(0, x - r), min(w, x + r + 1)):
            level = _level(m[yy, xx], p)
            if level is None:
                continue
            wt = colour[np.abs(g[y, x] - g[yy, xx]).sum()] * space[(yy - y) ** 2 + (xx - x) ** 2]
            weights[level] = weights.get(level, 0) + int(wt)
            values[level] = values.get(level, 0) + int(wt) * int(m[yy, xx])
    total, acc = sum(weights.values()), 0
    for level in sorted(weights):
        acc += weights[level]
        if 2 * acc >= total:
            break
    if _level(m[y, x], p) == level:
        return int(m[y, x])
    ws = weights[level]
    return (2 * values[level] + ws) // (2 * ws)


def postprocess(raw_left, raw_right, p, guide=None):
    h, w = raw_left.shape
    checked = raw_left.copy()
    if p["lr_max_diff"] >= 0:
        tol = round(p["lr_max_diff"] * 16)
        for y in range(h):
            for x in range(w):
                d = int(raw_left[y, x])
                xr = x - ((d + 8) // 16)
                ok = 0 <= xr < w and raw_right[y, xr] != INVALID and abs(int(raw_right[y, xr]) - d) <= tol
                checked[y, x] = d if ok else INVALID
        for y in range(h):
            _border_occlusion(checked[y], w)
    filled = checked.copy()
    if p["fill"] in ("background", "weighted"):
        for y in range(h):
            valid = np.flatnonzero(checked[y] != INVALID)
            for x in np.flatnonzero(checked[y] == INVALID):
                before, after = valid[valid < x], valid[valid > x]
                cands = ([checked[y, before[-1]]] if len(before) else []) + (
                    [checked[y, after[0]]] if len(after) else []
                )
                filled[y, x] = min(cands) if cands else INVALID
                span = p["fill_interpolate"] * 16
                if len(cands) == 2 and span > 0 and abs(int(cands[0]) - int(cands[1])) <= span:
                    xl, xr, dl, dr = int(before[-1]), int(after[0]), int(cands[0]), int(cands[1])
                    filled[y, x] = dl + (2 * (dr - dl) * (x - xl) + (xr - xl)) // (2 * (xr - xl))
    background = filled.copy()  # the weighted fill votes with the background fill, strips included
    strip = np.zeros((h, w), bool)
    if p["fill"] in ("background", "weighted") and p["border_fit"]:
        for y in range(h):
            for x, v in border_strips(checked, y, p).items():
                filled[y, x], strip[y, x] = v, True
    if p["fill"] == "weighted":
        for y, x in zip(*np.nonzero((checked == INVALID) & ~strip)):
            filled[y, x] = weighted_median_at(background, guide, y, x, p["fill_radius"], p)
    final = filled.copy()
    r = p["median"] // 2
    if p["median"]:
        for y in range(h):
            for x in range(w):
                if filled[y, x] == INVALID:
                    continue
                win = filled[max(0, y - r) : y + r + 1, max(0, x - r) : x + r + 1].ravel()
                vals = np.sort(win[win != INVALID])
                final[y, x] = vals[(len(vals) - 1) // 2]
    if p["weighted_median"]:
        before = final.copy()
        for y in range(h):
            for x in range(w):
                final[y, x] = weighted_median_at(before, guide, y, x, p["weighted_median"], p)
    return checked, filled, final
