"""Procedural textures of the synthetic scenes (float32 BGR in [0, 255] unless stated)."""

from __future__ import annotations

import cv2
import numpy as np
import numpy.typing as npt

Uint8Image = npt.NDArray[np.uint8]


def fbm(rng, h, w, *, cell, octaves=5, persistence=0.55, min_cell=1.5):
    """Multi-octave value noise, ``(h, w)`` float32, roughly in ``[0, 1]``."""
    out = np.zeros((h, w), np.float32)
    amp, total = 1.0, 0.0
    for _ in range(octaves):
        gh = int(np.ceil(h / cell)) + 2
        gw = int(np.ceil(w / cell)) + 2
        grid = rng.random((gh, gw), dtype=np.float32)
        out += amp * cv2.resize(grid, (w, h), interpolation=cv2.INTER_CUBIC)
        total += amp
        amp *= persistence
        cell = max(cell / 2.0, min_cell)
    out -= out.mean()
    out *= 0.2 / (out.std() + 1e-6)
    return np.clip(out + 0.5, 0.0, 1.0)


def hsv(h, s, v):
    """One BGR colour (float32, 0..255) from hue in degrees, s and v in [0, 1]."""
    px = np.array([[[(h % 360) / 2, s * 255, v * 255]]], np.float32)
    px = np.clip(px, 0, [179, 255, 255]).astype(np.uint8)
    return cv2.cvtColor(px, cv2.COLOR_HSV2BGR)[0, 0].astype(np.float32)


def _palette(rng, n, *, hue, hue_spread, sat, val):
    """``n`` colours ordered dark to light around ``hue``; ``(n, 3)`` float32."""
    vals = np.sort(rng.uniform(*val, n))
    return np.stack([hsv(hue + rng.uniform(-hue_spread, hue_spread),
                          rng.uniform(*sat), v) for v in vals])


def _colorize(field, stops):
    """Map a ``[0, 1]`` field through colour stops; ``(h, w, 3)`` float32."""
    xs = np.linspace(0.0, 1.0, len(stops))
    t = np.linspace(0.0, 1.0, 256)
    lut = np.stack([np.interp(t, xs, stops[:, c]) for c in range(3)], axis=1)
    idx = np.clip(field * 255 + 0.5, 0, 255).astype(np.uint8)
    return lut.astype(np.float32)[idx]


def _shade(img, field, amount):
    """Multiply by ``1 + amount (field - 0.5)``."""
    return img * (1.0 + amount * (field - 0.5))[..., None]


def _bricks(rng, h, w, *, row_h, length, jitter=0.15):
    """Irregular running bond: ``(labels (h, w) int64, joint distance (h, w))``."""
    heights = []
    while sum(heights) < h + row_h:
        heights.append(row_h * rng.uniform(1 - jitter, 1 + jitter))
    edges_y = np.concatenate([[0.0], np.cumsum(heights)]) - rng.uniform(0, row_h)
    ys = np.arange(h) + 0.5
    row = np.searchsorted(edges_y, ys, side="right") - 1
    dy = np.minimum(ys - edges_y[row], edges_y[row + 1] - ys)
    xs = np.arange(w) + 0.5
    n_rows = len(heights)
    max_cols = int(w / (row_h * length[0])) + 3
    col = np.zeros((n_rows, w), np.int64)
    dx = np.zeros((n_rows, w), np.float32)
    for r in range(n_rows):
        widths = row_h * rng.uniform(*length, max_cols)
        ex = np.concatenate([[0.0], np.cumsum(widths)]) - rng.uniform(0, widths[0])
        c = np.searchsorted(ex, xs, side="right") - 1
        col[r] = c
        dx[r] = np.minimum(xs - ex[c], ex[c + 1] - xs)
    labels = row[:, None] * (max_cols + 1) + col[row]
    dist = np.minimum(dx[row], dy[:, None].astype(np.float32))
    return labels, dist


def _per_label(rng, labels):
    """One random value in ``[0, 1)`` per label, gathered to ``labels`` shape."""
    return rng.random(int(labels.max()) + 1, dtype=np.float32)[labels]


def sky_texture(rng, h, w, geo, v0) -> Uint8Image:
    """Vertical gradient with soft clouds (reference-pixel texels)."""
    overcast = rng.random() < 0.3
    hue = rng.uniform(200, 225)
    top = hsv(hue, 0.05 if overcast else rng.uniform(0.45, 0.7), 0.75)
    horizon = hsv(hue, 0.03 if overcast else 0.2, 0.95)
    t = np.clip((np.arange(h) + v0) / max(geo.cy, 1.0), 0.0, 1.0)[:, None, None]
    img = top * (1 - t) + horizon * t
    small = (max(h // 4, 2), max(w // 4, 2))
    clouds = fbm(rng, *small, cell=40 * geo.scale / 4, octaves=4)
    clouds = cv2.resize(clouds, (w, h), interpolation=cv2.INTER_LINEAR)
    cover = np.clip((clouds - rng.uniform(0.45, 0.6)) * 4.0, 0.0, 1.0)[..., None]
    img = img * (1 - cover) + np.float32(245.0) * cover
    return np.clip(img, 0, 255).astype(np.uint8)


def backdrop_texture(rng, h, w, s, ground_row):
    """Street facade or hillside with a skyline; ``(texture, alpha)``."""
    fine = fbm(rng, h, w, cell=6 * s, octaves=3)
    large = fbm(rng, h, w, cell=90 * s, octaves=3)
    horizon = ground_row - rng.uniform(0.3, 0.55) * h  # mean skyline row
    if rng.random() < 0.6:  # town
        img = np.zeros((h, w, 3), np.float32)
        skyline = np.zeros(w, np.float32)
        x = 0
        while x < w:
            bw = int(rng.uniform(0.15, 0.45) * w) + 4
            sl = slice(x, min(x + bw, w))
            skyline[sl] = horizon + rng.uniform(-0.18, 0.12) * h
            img[:, sl] = _facade(rng, h, sl.stop - sl.start, s, skyline[x],
                                 ground_row, fine[:, sl])
            x += bw
    else:  # hillside
        prof = fbm(rng, 8, w, cell=120 * s, octaves=4)[4]
        skyline = horizon + (prof - 0.5) * 0.35 * h
        stops = _palette(rng, 4, hue=rng.uniform(60, 110), hue_spread=25,
                         sat=(0.25, 0.55), val=(0.2, 0.65))
        img = _colorize(0.6 * large + 0.4 * fine, stops)
        n = int(h * w / (np.pi * (8 * s + 1) * (5.5 * s + 1))) + 1  # cover ~1x
        for _ in range(n):  # bushes and rocks
            c = (int(rng.integers(w)), int(rng.integers(h)))
            ax = (int(rng.uniform(2, 14) * s) + 1, int(rng.uniform(2, 9) * s) + 1)
            col = stops[rng.integers(len(stops))] * rng.uniform(0.6, 1.25)
            cv2.ellipse(img, c, ax, rng.uniform(0, 180), 0, 360,
                        col.tolist(), -1, cv2.LINE_AA)
        img = _shade(img, fine, 0.6)
    img = _shade(img, large, 0.35)
    rows = np.arange(h, dtype=np.float32)[:, None]
    alpha = np.clip(rows - skyline[None, :] + 0.5, 0.0, 1.0)
    tex = np.clip(img, 0, 255).astype(np.uint8)
    return tex, (255 * alpha + 0.5).astype(np.uint8)


def _facade(rng, h, w, s, top, ground_row, fine):
    """One building: bricks or plaster, irregular windows."""
    hue = rng.uniform(0, 50)
    if rng.random() < 0.5:
        labels, dist = _bricks(rng, h, w, row_h=max(3.0, rng.uniform(7, 11) * s),
                               length=(1.6, 3.2))
        stops = _palette(rng, 3, hue=hue, hue_spread=8, sat=(0.3, 0.6),
                         val=(0.35, 0.75))
        img = _colorize(0.55 * _per_label(rng, labels) + 0.45 * fine, stops)
        mortar = hsv(hue, 0.08, rng.uniform(0.55, 0.8))
        t = np.clip(dist - 0.6 * max(s, 0.5), 0.0, 1.0)[..., None]
        img = img * t + mortar * (1 - t)
    else:
        stops = _palette(rng, 3, hue=hue + 20, hue_spread=15, sat=(0.05, 0.35),
                         val=(0.5, 0.9))
        img = _colorize(fine, stops)
    # windows on a jittered, irregular grid
    ww, wh = rng.uniform(10, 22) * s, rng.uniform(14, 28) * s
    frame = hsv(rng.uniform(0, 360), rng.uniform(0, 0.3), rng.uniform(0.7, 0.95))
    y = top + rng.uniform(0.5, 1.5) * wh
    while y + wh < ground_row - 0.5 * wh:
        x = rng.uniform(0.2, 1.0) * ww
        while x + ww < w - 0.2 * ww:
            if rng.random() < 0.8:
                glass = hsv(rng.uniform(180, 240), rng.uniform(0.1, 0.5),
                             rng.uniform(0.1, 0.45))
                if rng.random() < 0.15:
                    glass = hsv(rng.uniform(35, 55), 0.5, 0.9)  # lit window
                p0 = (int(x), int(y))
                p1 = (int(x + ww * rng.uniform(0.8, 1.2)), int(y + wh))
                cv2.rectangle(img, p0, p1, frame.tolist(), -1)
                m = max(1, int(2 * s))
                cv2.rectangle(img, (p0[0] + m, p0[1] + m), (p1[0] - m, p1[1] - m),
                              glass.tolist(), -1)
            x += ww * rng.uniform(1.6, 2.6)
        y += wh * rng.uniform(1.6, 2.2)
    return img


def ground_texture(rng, h, w, s, minify) -> Uint8Image:
    """Gravel or paving; rows far away are prefiltered (``minify`` per row)."""
    fine = fbm(rng, h, w, cell=5 * s, octaves=3)
    large = fbm(rng, h, w, cell=80 * s, octaves=3)
    hue = rng.uniform(20, 60)
    stops = _palette(rng, 4, hue=hue, hue_spread=15, sat=(0.1, 0.4),
                     val=(0.3, 0.75))
    if rng.random() < 0.5:  # gravel and pebbles
        img = _colorize(0.5 * large + 0.5 * fine, stops)
        n = int(0.32 * h * w / (np.pi * (4.25 * s + 1) * (3.25 * s + 1))) + 1
        cols = _palette(rng, 6, hue=hue, hue_spread=30, sat=(0.0, 0.3),
                        val=(0.3, 0.95))
        for _ in range(n):
            c = (int(rng.integers(w)), int(rng.integers(h)))
            ax = (int(rng.uniform(1.5, 7) * s) + 1, int(rng.uniform(1.5, 5) * s) + 1)
            ang = rng.uniform(0, 180)
            col = cols[rng.integers(len(cols))]
            cv2.ellipse(img, c, ax, ang, 0, 360, (col * 0.55).tolist(), -1)
            cv2.ellipse(img, c, (max(ax[0] - 1, 1), max(ax[1] - 1, 1)), ang, 0,
                        360, col.tolist(), -1)
        img = _shade(img, fine, 0.5)
    else:  # irregular flagstones
        labels, dist = _bricks(rng, h, w, row_h=max(4.0, rng.uniform(18, 30) * s),
                               length=(0.8, 2.0), jitter=0.3)
        img = _colorize(0.5 * _per_label(rng, labels) + 0.5 * fine, stops)
        gap = hsv(rng.uniform(60, 100), rng.uniform(0.2, 0.5), rng.uniform(0.15, 0.35))
        t = np.clip(dist - 1.0 * max(s, 0.5), 0.0, 1.0)[..., None]
        img = img * t + gap * (1 - t)
        img = _shade(img, fine, 0.4)
    img = _shade(img, large, 0.4)
    # prefilter the far rows (one texel covers less than a pixel there)
    blurred = cv2.GaussianBlur(img, (0, 0), 1.2)
    wgt = np.clip(minify - 1.0, 0.0, 1.0).astype(np.float32)[:, None, None]
    img = img * (1 - wgt) + blurred * wgt
    return np.clip(img, 0, 255).astype(np.uint8)


def box_texture(rng, h, w, style, light, s) -> Uint8Image:
    """Planked crate or concrete pillar with posters; ``light`` shades a face."""
    fine = fbm(rng, h, w, cell=4 * s, octaves=3)
    if style == "crate":
        hue = rng.uniform(20, 45)
        stops = _palette(rng, 3, hue=hue, hue_spread=6, sat=(0.35, 0.6),
                         val=(0.35, 0.8))
        vertical = rng.random() < 0.5
        n_along = w if vertical else h
        plank = max(3.0, rng.uniform(7, 14) * s)
        edges = np.cumsum(plank * rng.uniform(0.7, 1.4, int(n_along / plank) + 3))
        idx = np.searchsorted(edges, np.arange(n_along) + 0.5)
        dist = np.minimum(np.arange(n_along) + 0.5 - np.r_[0, edges][idx],
                          edges[idx] - np.arange(n_along) - 0.5)
        grain_shape = (h, max(2, w // 10)) if not vertical else (max(2, h // 10), w)
        grain = cv2.resize(fbm(rng, *grain_shape, cell=3, octaves=3), (w, h))
        shade = rng.random(len(edges) + 1).astype(np.float32)[idx]
        if vertical:
            shade, dist = shade[None, :], dist[None, :]
        else:
            shade, dist = shade[:, None], dist[:, None]
        img = _colorize(np.clip(0.4 * shade + 0.6 * grain, 0, 1), stops)
        gap = np.clip(dist - 0.7, 0.0, 1.0).astype(np.float32)
        img *= (0.35 + 0.65 * gap)[..., None]
        b = max(1, int(3 * s))  # dark frame
        img[:b] *= 0.6
        img[-b:] *= 0.6
        img[:, :b] *= 0.6
        img[:, -b:] *= 0.6
    else:
        stops = _palette(rng, 3, hue=rng.uniform(0, 360), hue_spread=10,
                         sat=(0.0, 0.15), val=(0.4, 0.8))
        stains = fbm(rng, h, w, cell=30 * s, octaves=3)
        img = _colorize(0.5 * fine + 0.5 * stains, stops)
        for _ in range(int(rng.integers(1, 4))):  # posters
            pw, ph = (max(2, int(rng.uniform(0.25, 0.7) * w)),
                      max(2, int(rng.uniform(0.1, 0.3) * h)))
            x0 = int(rng.integers(0, max(1, w - pw)))
            y0 = int(rng.integers(0, max(1, h - ph)))
            col = hsv(rng.uniform(0, 360), rng.uniform(0.3, 0.8),
                       rng.uniform(0.4, 0.95))
            pf = fbm(rng, ph, pw, cell=max(2.0, 8 * s), octaves=2)
            img[y0:y0 + ph, x0:x0 + pw] = _colorize(
                pf, np.stack([col * 0.5, col, np.minimum(col * 1.4, 255)]))
        for _ in range(int(rng.integers(2, 6))):  # cracks
            pts = np.cumsum(rng.normal(0, 6 * s, (6, 2)), axis=0)
            pts += [rng.integers(w), rng.integers(h)]
            cv2.polylines(img, [pts.astype(np.int32)], False, (40, 40, 40), 1)
    img = _shade(img, fine, 0.3) * light
    return np.clip(img, 0, 255).astype(np.uint8)
