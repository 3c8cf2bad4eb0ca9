#!/usr/bin/python3
"""Hand labelling of the real-image set (data/real, format in data/real/README.md).

A person writes rough labels (data/real/rough/NAME.txt) while looking at the gridded, enlarged
image (`grid`); `snap` refines them on the image gradient alone (never with the frontend that
is scored) and writes data/real/labels/NAME.txt; `overlay` draws the result for a visual check.

    tools/label/label.py grid NAME [--scale 3] [--crop x0 y0 x1 y1]   -> /tmp/label_grid_NAME.png
    tools/label/label.py snap NAME|--all                               -> data/real/labels/NAME.txt
    tools/label/label.py overlay NAME [--scale 3]                      -> /tmp/label_overlay_NAME.png
    tools/label/label.py ridge NAME|--all                              -> offsets from the luma ridge

Rough label lines (px in the 320x240 image, # comments):
    m x1 y1 x2 y2 [g]     a straight marking stripe, rough end points on its centre line; pieces of
                          one stripe split by an occluder share the group id g
    c x y L|T|X           a marking corner / T-junction / intersection near (x, y)
    b x1 y1 x2 y2 ...     the field boundary (far edge of the field floor), left to right
    o x1 y1 x2 y2 ...     a don't-care polygon (robot, person, ball, lens border); two points: a box
    k x1 y1 x2 y2 ...     a curved marking (centre circle, lens-bent line): don't-care polyline
    K x1 y1 x2 y2 ...     the same, written as given (not snapped): an arc within 12 px of a brighter
                          stripe, onto which the snap would move it

Refinement ("snap"), per marking: luma profiles across the rough line every 1 px, smoothed
(Gaussian, sigma 0.7 px) and sampled every 0.1 px; the stripe's two sides are the strongest
rising and falling derivative (sub-pixel parabola), their mid-point a centre sample. Total least
squares lines are fitted to the centre samples (outliers > 1 px dropped, twice), the profiles
re-sampled across the fitted line and fitted again. A free end is where the stripe contrast
along the centre line falls to half its median; an end within 3 px of the image border is put
on the border (the pixels' outer edge, -0.5 or W-0.5); an end within 8 px of a labelled corner is the corner. A corner is the
intersection of the two fitted centre lines nearest to its rough position. Side edges (the edge
level of the benchmark) are the visible runs of each side line where the image gradient across
it has the right sign and at least 40 % of the side's median magnitude; each side line is
fitted to its own samples (a stripe tapers under perspective).
"""
import argparse
import glob
import math
import os
import sys

import cv2
import numpy as np

DATA = 'data/real'
W, H = 320, 240
# Free-end search (free_end): px inside / beyond the rough end, reference stretch, run below.
END_IN, END_OUT, END_REF, END_RUN = 10.0, 40.0, 15.0, 2.0
# Curve snapping (snap_curve): sample spacing, search reach, ridge side offset, px; min ridge, grey levels.
CURVE_STEP, CURVE_REACH, CURVE_SIDE, CURVE_MIN = 4.0, 12.0, 5.0, 12.0


def fail(where, msg):
    sys.exit(f'{where}: {msg}')


def load_rough(name):
    path = os.path.join(DATA, 'rough', name + '.txt')
    items = []
    with open(path) as f:
        for ln, line in enumerate(f, 1):
            line = line.split('#')[0].strip()
            if not line:
                continue
            tok = line.split()
            kind, rest = tok[0], tok[1:]
            where = f'{path}:{ln}'
            try:
                if kind == 'm':
                    if len(rest) not in (4, 5):
                        fail(where, 'm needs x1 y1 x2 y2 [group]')
                    items.append(('m', [float(v) for v in rest[:4]], int(rest[4]) if len(rest) == 5 else -1, where))
                elif kind == 'c':
                    if len(rest) != 3 or rest[2] not in ('L', 'T', 'X'):
                        fail(where, 'c needs x y L|T|X')
                    items.append(('c', [float(rest[0]), float(rest[1])], rest[2], where))
                elif kind in ('b', 'o', 'k', 'K'):
                    if len(rest) < 4 or len(rest) % 2:
                        fail(where, f'{kind} needs an even number (>= 4) of coordinates')
                    v = [float(x) for x in rest]
                    if kind == 'o' and len(v) == 4:  # a box x0 y0 x1 y1
                        v = [v[0], v[1], v[2], v[1], v[2], v[3], v[0], v[3]]
                    items.append((kind, v, None, where))
                else:
                    fail(where, f'unknown label kind "{kind}" (m, c, b, o, k, K)')
            except ValueError as e:
                fail(where, f'not a number: {e}')
    return items


def luma_of(img):
    b, g, r = [c.astype(np.float32) for c in cv2.split(img)]
    return 0.114 * b + 0.587 * g + 0.299 * r


def bilinear(lum, xs, ys):
    xs = np.clip(xs, 0, W - 1.001)
    ys = np.clip(ys, 0, H - 1.001)
    x0 = np.floor(xs).astype(int)
    y0 = np.floor(ys).astype(int)
    fx, fy = xs - x0, ys - y0
    return ((1 - fy) * ((1 - fx) * lum[y0, x0] + fx * lum[y0, x0 + 1]) +
            fy * ((1 - fx) * lum[y0 + 1, x0] + fx * lum[y0 + 1, x0 + 1]))


def parabola(d, i):
    if 0 < i < len(d) - 1:
        den = d[i - 1] - 2 * d[i] + d[i + 1]
        if den != 0:
            return i + 0.5 * (d[i - 1] - d[i + 1]) / den
    return float(i)


def tls(pts):
    c = pts.mean(axis=0)
    _, _, vt = np.linalg.svd(pts - c)
    u = vt[0]
    return c, u / np.linalg.norm(u)


STEP = 0.1


def profiles(lum, c, u, ts, reach):
    n = np.array([-u[1], u[0]])
    ss = np.arange(-reach, reach + 1e-9, STEP)
    pts = c[None, :] + ts[:, None] * u[None, :]
    xs = pts[:, 0:1] + ss[None, :] * n[0]
    ys = pts[:, 1:2] + ss[None, :] * n[1]
    prof = bilinear(lum, xs, ys)
    k = int(round(0.7 * 3 / STEP))
    g = np.exp(-0.5 * (np.arange(-k, k + 1) * STEP / 0.7) ** 2)
    g /= g.sum()
    prof = np.array([np.convolve(p, g, mode='same') for p in prof])
    return ss, pts, n, prof


def stripe_samples(lum, c, u, t0, t1, reach):
    ts = np.arange(t0 + 1.0, t1 - 1.0 + 1e-9, 1.0)
    if len(ts) < 3:
        return None
    ss, pts, n, prof = profiles(lum, c, u, ts, reach)
    d = np.gradient(prof, axis=1)
    m = int(round(0.7 * 3 / STEP)) + 1
    out = []
    for i in range(len(ts)):
        di = d[i, m:-m]
        ip = int(np.argmax(di))
        im = int(np.argmin(di))
        if not ip < im or di[ip] <= 0.2 or di[im] >= -0.2:
            continue
        sp = ss[m + 0] + parabola(di, ip) * STEP
        sm = ss[m + 0] + parabola(di, im) * STEP
        out.append((ts[i], sp, sm, di[ip], -di[im]))
    return np.array(out) if out else None


def fit_marking(lum, p1, p2, where):
    """Fits with a 9 px search reach, or 4 px when fewer than half the profiles agree with the
    fit (a thin far stripe next to the stronger edges of the field boundary)."""
    m = fit_marking_reach(lum, p1, p2, where, 9.0)
    if m['samples'] < 0.5 * m['total']:
        m4 = fit_marking_reach(lum, p1, p2, where, 4.0)
        if m4['samples'] > m['samples']:
            m = m4
    return m


def fit_marking_reach(lum, p1, p2, where, reach):
    p1, p2 = np.array(p1), np.array(p2)
    c, u = 0.5 * (p1 + p2), (p2 - p1) / np.linalg.norm(p2 - p1)
    half = 0.5 * np.linalg.norm(p2 - p1)
    for it in range(3):
        s = stripe_samples(lum, c, u, -half, half, reach)
        if s is None or len(s) < 5:
            fail(where, 'no stripe found across the rough line')
        n = np.array([-u[1], u[0]])
        c_prev, u_prev, n_prev = c.copy(), u.copy(), n.copy()
        mid = 0.5 * (s[:, 1] + s[:, 2])
        pts = c[None, :] + s[:, 0:1] * u[None, :] + mid[:, None] * n[None, :]
        keep = np.ones(len(pts), bool)
        for _ in range(2):
            cc, uu = tls(pts[keep])
            nn = np.array([-uu[1], uu[0]])
            res = (pts - cc) @ nn
            keep = np.abs(res) <= 1.0
            if keep.sum() < 5:
                fail(where, 'stripe samples too scattered')
        if uu @ u < 0:
            uu = -uu
        # Re-centre on the fitted line, keep the rough extent.
        t1 = (p1 - cc) @ uu
        t2 = (p2 - cc) @ uu
        c = cc + 0.5 * (t1 + t2) * uu
        u = uu
        half = 0.5 * (t2 - t1)
        reach = min(12.0, max(3.0, 1.5 * float(np.median(s[keep, 2] - s[keep, 1])) + 1.5))
    n = np.array([-u[1], u[0]])
    res = (pts[keep] - cc) @ nn
    width = float(np.median(s[keep, 2] - s[keep, 1]))
    # Side edges fitted on their own samples: under perspective a stripe tapers, so its sides
    # are not parallel to its centre line.
    sides = []
    for col in (1, 2):
        ep = c_prev[None, :] + s[keep, 0:1] * u_prev[None, :] + s[keep, col][:, None] * n_prev[None, :]
        ok = np.ones(len(ep), bool)
        for _ in range(2):
            ec, eu = tls(ep[ok])
            en = np.array([-eu[1], eu[0]])
            ok = np.abs((ep - ec) @ en) <= 1.0
            if ok.sum() < 3:
                ok[:] = True
                break
        if eu @ u < 0:
            eu = -eu
        sides.append((ec, eu))
    # Straightness: 8 px bin means of the residual.
    tk = s[keep, 0]
    dev = 0.0
    for b0 in np.arange(tk.min(), tk.max(), 8.0):
        sel = (tk >= b0) & (tk < b0 + 8)
        if sel.sum() >= 3:
            dev = max(dev, abs(float(res[sel].mean())))
    return dict(c=c, u=u, half=half, width=width, sides=sides, rms=float(np.sqrt(np.mean(res ** 2))), dev=dev,
                off_p=float(np.median(s[keep, 1] - 0.5 * (s[keep, 1] + s[keep, 2]))),
                off_m=float(np.median(s[keep, 2] - 0.5 * (s[keep, 1] + s[keep, 2]))),
                samples=int(keep.sum()), total=len(s), where=where)


def stripe_contrast(lum, c, u, ts, width):
    n = np.array([-u[1], u[0]])
    pts = c[None, :] + ts[:, None] * u[None, :]
    inner = np.mean([bilinear(lum, pts[:, 0] + s * n[0], pts[:, 1] + s * n[1])
                     for s in np.linspace(-0.25 * width, 0.25 * width, 3)], axis=0)
    o = 0.5 * width + 2.0
    outer = 0.5 * (bilinear(lum, pts[:, 0] + o * n[0], pts[:, 1] + o * n[1]) +
                   bilinear(lum, pts[:, 0] - o * n[0], pts[:, 1] - o * n[1]))
    return inner - outer


def free_end(lum, m, t, sign):
    """Sub-pixel end of the stripe near line coordinate t, the stripe lying towards -sign.

    The rough end is a hand-given point and may lie well short of or past the stripe's end (a
    far stripe fades over tens of px), so the end is searched from END_IN px inside the rough
    end out to END_OUT px beyond it: the first place where the stripe contrast falls below half
    the contrast just inside it (the END_REF px before the search start, or the whole body when
    that is shorter) and stays below for END_RUN px; the rough end stands when the stripe is
    already faint where the search starts. A stripe is brighter than both sides, so a
    robot, its shadow, the field boundary's wall or the image border all end it."""
    c, u, w = m['c'], m['u'], m['width']
    lo, hi = -m['half'], m['half']
    start = t - END_IN * sign
    ref_ts = np.arange(start - END_REF * sign, start, 0.5 * sign)
    ref_ts = ref_ts[(ref_ts >= lo) & (ref_ts <= hi)]
    if len(ref_ts) < 8:
        ref_ts = np.arange(lo + 3, hi - 3, 1.0)
    ref = float(np.median(stripe_contrast(lum, c, u, ref_ts, w))) if len(ref_ts) else 0.0
    ts = np.arange(start, t + END_OUT * sign + 1e-9 * sign, 0.25 * sign)
    pts = c[None, :] + ts[:, None] * u[None, :]
    inside = (pts[:, 0] >= 0) & (pts[:, 0] <= W - 1) & (pts[:, 1] >= 0) & (pts[:, 1] <= H - 1)
    if not inside.all():
        ts = ts[:int(np.argmin(inside))]
    if len(ts) < 2 or ref <= 0:
        return t
    con = stripe_contrast(lum, c, u, ts, w)
    below = con < 0.5 * ref
    run = int(round(END_RUN / 0.25))
    for i in range(1, len(ts)):
        if below[i] and not below[i - 1] and below[i:i + run].all():
            f = (con[i - 1] - 0.5 * ref) / (con[i - 1] - con[i])
            return ts[i - 1] + f * (ts[i] - ts[i - 1])
    if below[0]:
        # Already faint inside the rough end (a crossing stripe brightens both sides, or the
        # reference stretch is not stripe): the hand-given end stands.
        return t
    return ts[-1]


def border_t(c, u, t, sign):
    """Line coordinate where the line leaves the image nearest to t (within 10 px): the image
    is the box [-0.5, W-0.5] x [-0.5, H-0.5] of the pixels' outer edges (pixel centres are
    integers), where the frontend clips its lines too."""
    best = None
    for k, lim in ((0, -0.5), (0, W - 0.5), (1, -0.5), (1, H - 0.5)):
        if abs(u[k]) < 1e-9:
            continue
        tt = (lim - c[k]) / u[k]
        q = c + tt * u
        if -0.51 <= q[0] <= W - 0.49 and -0.51 <= q[1] <= H - 0.49 and abs(tt - t) <= 10:
            if best is None or abs(tt - t) < abs(best - t):
                best = tt
    return best if best is not None else t


def intersect(m1, m2):
    a = np.column_stack([m1['u'], -m2['u']])
    if abs(np.linalg.det(a)) < 1e-6:
        return None
    t = np.linalg.solve(a, m2['c'] - m1['c'])
    return m1['c'] + t[0] * m1['u']


def edge_runs(lum, gx, gy, a, b, normal, sign):
    """Visible runs of an edge line a-b: gradient across it of sign `sign` along `normal`."""
    L = np.linalg.norm(b - a)
    u = (b - a) / L
    ts = np.arange(0.0, L + 1e-9, 0.5)
    pts = a[None, :] + ts[:, None] * u[None, :]
    best = np.zeros(len(ts))
    for off in (-1.0, -0.5, 0.0, 0.5, 1.0):
        q = pts + off * normal[None, :]
        g = sign * (bilinear(gx, q[:, 0], q[:, 1]) * normal[0] + bilinear(gy, q[:, 0], q[:, 1]) * normal[1])
        best = np.maximum(best, g)
    inside = (pts[:, 0] >= 1) & (pts[:, 0] <= W - 2) & (pts[:, 1] >= 1) & (pts[:, 1] <= H - 2)
    med = np.median(best[inside]) if inside.any() else 0
    on = (best >= 0.4 * med) & (best > 4.0) & inside
    runs, i = [], 0
    while i < len(on):
        if not on[i]:
            i += 1
            continue
        j = i
        while j + 1 < len(on) and (on[j + 1] or (j + 5 < len(on) and on[j + 2:j + 6].any())):
            j += 1
        while not on[j]:
            j -= 1
        if ts[j] - ts[i] >= 4.0:
            runs.append((a + ts[i] * u, a + ts[j] * u))
        i = j + 1
    return runs


def snap_curve(lum, v):
    """A hand-given curve polyline moved onto its stripe: resampled every CURVE_STEP px, each
    sample moved along the polyline's normal (up to CURVE_REACH px) to the brightest ridge
    (luma there minus the mean luma CURVE_SIDE px to either side, after the blur of `lum`);
    samples without a ridge of at least CURVE_MIN grey levels stay where they are. The curve is
    a don't-care stroke, so it must lie on the stripe, not beside it."""
    pts = np.array(v, dtype=float).reshape(-1, 2)
    out = []
    for p0, p1 in zip(pts[:-1], pts[1:]):
        L = np.linalg.norm(p1 - p0)
        if L < 1e-9:
            continue
        u = (p1 - p0) / L
        n = np.array([-u[1], u[0]])
        for t in np.arange(0.0, L, CURVE_STEP):
            q = p0 + t * u
            offs = np.arange(-CURVE_REACH, CURVE_REACH + 1e-9, 0.5)
            cx, cy = q[0] + offs * n[0], q[1] + offs * n[1]
            ridge = bilinear(lum, cx, cy) - 0.5 * (bilinear(lum, cx + CURVE_SIDE * n[0], cy + CURVE_SIDE * n[1]) +
                                                   bilinear(lum, cx - CURVE_SIDE * n[0], cy - CURVE_SIDE * n[1]))
            k = int(np.argmax(ridge))
            out.append(q + offs[k] * n if ridge[k] >= CURVE_MIN else q)
    out.append(pts[-1])
    return [float(np.clip(c, 0, (W - 1) if i % 2 == 0 else (H - 1))) for i, c in enumerate(np.array(out).ravel())]


def snap(name):
    img = cv2.imread(os.path.join(DATA, 'images', name + '.jpg'))
    if img is None:
        fail(name, 'image not found')
    lum = luma_of(img)
    lum_s = cv2.GaussianBlur(lum, (0, 0), 0.7)
    gx = cv2.Sobel(lum_s, cv2.CV_32F, 1, 0, ksize=3) / 8.0
    gy = cv2.Sobel(lum_s, cv2.CV_32F, 0, 1, ksize=3) / 8.0
    items = load_rough(name)
    marks = []
    for kind, v, extra, where in items:
        if kind == 'm':
            m = fit_marking(lum, v[:2], v[2:], where)
            m['group'] = extra
            m['rough'] = (np.array(v[:2]), np.array(v[2:]))
            marks.append(m)
    corners = []
    for kind, v, extra, where in items:
        if kind != 'c':
            continue
        q = np.array(v)
        cand = []
        for k, m in enumerate(marks):
            d = abs((q - m['c']) @ np.array([-m['u'][1], m['u'][0]]))
            t = (q - m['c']) @ m['u']
            if d <= 8 and -m['half'] - 10 <= t <= m['half'] + 10:
                cand.append((d, k))
        best = None
        for i in range(len(cand)):
            for j in range(i + 1, len(cand)):
                m1, m2 = marks[cand[i][1]], marks[cand[j][1]]
                ang = math.degrees(math.acos(min(1.0, abs(float(m1['u'] @ m2['u'])))))
                if ang < 15:
                    continue
                p = intersect(m1, m2)
                if p is not None and np.linalg.norm(p - q) <= 8 and (best is None or np.linalg.norm(p - q) < best[0]):
                    best = (np.linalg.norm(p - q), p)
        if best is None:
            fail(where, 'corner: no two labelled markings cross within 8 px of it')
        corners.append((extra, best[1], where))
    out_marks = []
    for m in marks:
        c, u = m['c'], m['u']
        ends = []
        for sign, rough in ((-1, m['rough'][0]), (1, m['rough'][1])):
            t = float((rough - c) @ u)
            near = [p for _, p, _ in corners if np.linalg.norm(p - rough) <= 8]
            if near:
                t = float((near[0] - c) @ u)
            elif min(rough[0], rough[1], W - 1 - rough[0], H - 1 - rough[1]) <= 3:
                t = border_t(c, u, t, sign)
            else:
                t = free_end(lum, m, t, sign)
            ends.append(t)
        a, b = c + ends[0] * u, c + ends[1] * u
        n = np.array([-u[1], u[0]])
        edges = []
        ext = 0.5 * m['width'] + 1.0
        ea, eb = c + (ends[0] - ext) * u, c + (ends[1] + ext) * u
        for (ec, eu), sign in zip(m['sides'], (1.0, -1.0)):
            en = np.array([-eu[1], eu[0]])
            # The side line between the points across from the extended ends.
            qa = ea + ((ec - ea) @ en) / (n @ en) * n
            qb = eb + ((ec - eb) @ en) / (n @ en) * n
            for r0, r1 in edge_runs(lum_s, gx, gy, qa, qb, en if en @ n > 0 else -en, sign):
                edges.append((r0, r1))
        out_marks.append((a, b, m, edges))
        if m['dev'] > 1.0:
            print(f"{m['where']}: warning: not straight (bin mean {m['dev']:.2f} px off the fit); label it k")
    path = os.path.join(DATA, 'labels', name + '.txt')
    with open(path + '.tmp', 'w') as f:
        f.write(f'# stereoloc real-image labels (data/real/README.md); image {name}.jpg {W}x{H}; px\n')
        for i, (a, b, m, edges) in enumerate(out_marks):
            f.write(f"marking {a[0]:.2f} {a[1]:.2f} {b[0]:.2f} {b[1]:.2f} width {m['width']:.2f} group {m['group']}"
                    f" rms {m['rms']:.2f}\n")
            for r0, r1 in edges:
                f.write(f'edge {r0[0]:.2f} {r0[1]:.2f} {r1[0]:.2f} {r1[1]:.2f} of {i}\n')
        for typ, p, _ in corners:
            f.write(f'corner {typ} {p[0]:.2f} {p[1]:.2f}\n')
        names = {'b': 'boundary', 'o': 'dontcare', 'k': 'curve', 'K': 'curve'}
        for kind, v, extra, where in items:
            if kind == 'k':
                v = snap_curve(lum_s, v)
            if kind in names:
                f.write(names[kind] + ' ' + ' '.join(f'{x:.1f}' for x in v) + '\n')
    os.replace(path + '.tmp', path)
    print(f'{name}: {len(out_marks)} markings, {len(corners)} corners, rms ' +
          ' '.join(f"{m['rms']:.2f}" for _, _, m, _ in out_marks))


def grid(name, scale, crop, img=None, write=True):
    if img is None:
        img = cv2.imread(os.path.join(DATA, 'images', name + '.jpg'))
    x0, y0, x1, y1 = crop if crop else (0, 0, W, H)
    sub = img[y0:y1, x0:x1]
    big = cv2.resize(sub, None, fx=scale, fy=scale, interpolation=cv2.INTER_CUBIC)
    step = 10 if scale <= 3 else 5
    for x in range((x0 // step) * step, x1 + 1, step):
        X = int((x - x0) * scale)
        col = (0, 255, 255) if x % 50 == 0 else (90, 90, 90)
        cv2.line(big, (X, 0), (X, big.shape[0]), col, 1)
        if x % 50 == 0:
            cv2.putText(big, str(x), (X + 2, 12), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (0, 255, 255), 1)
    for y in range((y0 // step) * step, y1 + 1, step):
        Y = int((y - y0) * scale)
        col = (0, 255, 255) if y % 50 == 0 else (90, 90, 90)
        cv2.line(big, (0, Y), (big.shape[1], Y), col, 1)
        if y % 50 == 0:
            cv2.putText(big, str(y), (2, Y - 2), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (0, 255, 255), 1)
    if not write:
        return big
    out = f'/tmp/label_grid_{name}.png'
    cv2.imwrite(out, big)
    print(out)


def overlay(name, scale, write=True):
    img = cv2.imread(os.path.join(DATA, 'images', name + '.jpg'))
    big = cv2.resize(img, None, fx=scale, fy=scale, interpolation=cv2.INTER_CUBIC)
    P = lambda x, y: (int(round(x * scale + scale / 2 - 0.5)), int(round(y * scale + scale / 2 - 0.5)))
    with open(os.path.join(DATA, 'labels', name + '.txt')) as f:
        for line in f:
            t = line.split()
            if not t or t[0].startswith('#'):
                continue
            if t[0] == 'marking':
                v = [float(x) for x in t[1:5]]
                cv2.line(big, P(v[0], v[1]), P(v[2], v[3]), (255, 0, 255), 1)
            elif t[0] == 'edge':
                v = [float(x) for x in t[1:5]]
                cv2.line(big, P(v[0], v[1]), P(v[2], v[3]), (255, 255, 0), 1)
            elif t[0] == 'corner':
                x, y = float(t[2]), float(t[3])
                cv2.drawMarker(big, P(x, y), (0, 0, 255), cv2.MARKER_CROSS, 14, 1)
                cv2.putText(big, t[1], (P(x, y)[0] + 5, P(x, y)[1] - 5), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 0, 255), 1)
            else:
                v = np.array([float(x) for x in t[1:]]).reshape(-1, 2)
                pts = np.array([P(*q) for q in v], np.int32)
                col = {'boundary': (0, 255, 255), 'dontcare': (0, 128, 255), 'curve': (128, 128, 128)}[t[0]]
                cv2.polylines(big, [pts], t[0] == 'dontcare', col, 1)
    if not write:
        return big
    out = f'/tmp/label_overlay_{name}.png'
    cv2.imwrite(out, big)
    print(out)


# Ridge check (ridge): sample spacing along a marking, px; least stripe contrast, grey levels;
# offsets (px) at which a marking is listed.
RIDGE_STEP, RIDGE_MIN, RIDGE_MEDIAN, RIDGE_P80 = 2.0, 8.0, 1.0, 1.5


def ridge(name):
    """Prints the markings of labels/NAME.txt whose centre line lies off the stripe's luma ridge:
    every RIDGE_STEP px along the line a profile across it (Gaussian sigma 0.7 px, 0.1 px steps,
    out to half the width + 4 px) gives the middle of the bright run above half the peak's rise
    over the brighter of the two sides (1.5 px beyond the profile), where that rise is at least
    RIDGE_MIN. A marking is listed when the median offset exceeds RIDGE_MEDIAN or its 80th
    percentile RIDGE_P80. It uses the image alone, never the frontend that is scored: a snap
    drawn across two stripes, or onto a second stripe beside the first, shows here."""
    img = cv2.imread(os.path.join(DATA, 'images', name + '.jpg'))
    lum = cv2.GaussianBlur(luma_of(img), (0, 0), 0.7)
    with open(os.path.join(DATA, 'labels', name + '.txt')) as f:
        lines = f.readlines()
    for ln, line in enumerate(lines, 1):
        t = line.split()
        if not t or t[0] != 'marking':
            continue
        x1, y1, x2, y2, w = (float(v) for v in (t[1], t[2], t[3], t[4], t[6]))
        p1 = np.array([x1, y1])
        d = np.array([x2 - x1, y2 - y1])
        length = float(np.linalg.norm(d))
        u = d / length
        n = np.array([-u[1], u[0]])
        reach = 0.5 * w + 4.0
        ss = np.arange(-reach, reach + 1e-9, STEP)
        offs = []
        for s_ in np.arange(RIDGE_STEP, length - RIDGE_STEP + 1e-9, RIDGE_STEP):
            c = p1 + s_ * u
            q = c[None, :] + ss[:, None] * n[None, :]
            side = c[None, :] + np.array([-(reach + 1.5), reach + 1.5])[:, None] * n[None, :]
            allq = np.vstack([q, side])
            if (allq < 0).any() or (allq[:, 0] > W - 1.001).any() or (allq[:, 1] > H - 1.001).any():
                continue
            prof = bilinear(lum, q[:, 0], q[:, 1])
            base = float(bilinear(lum, side[:, 0], side[:, 1]).max())
            i = int(np.argmax(prof))
            if prof[i] - base < RIDGE_MIN:
                continue
            half = 0.5 * (prof[i] + base)
            a, b = i, i
            while a > 0 and prof[a] > half:
                a -= 1
            while b < len(prof) - 1 and prof[b] > half:
                b += 1
            if a == 0 or b == len(prof) - 1:
                continue  # the bright run reaches the profile's end: no middle to compare
            offs.append(abs(0.5 * (ss[a] + ss[b])))
        if len(offs) < 5:
            continue
        med, p80 = float(np.median(offs)), float(np.percentile(offs, 80))
        if med > RIDGE_MEDIAN or p80 > RIDGE_P80:
            print(f'{name}:{ln}: marking {x1:.1f} {y1:.1f} {x2:.1f} {y2:.1f} width {w:.2f}: '
                  f'{med:.2f} px median, {p80:.2f} px 80th percentile off the ridge ({len(offs)} samples)')


def main():
    global DATA
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument('cmd', choices=['grid', 'snap', 'overlay', 'sheet', 'oversheet', 'ridge'])
    ap.add_argument('name', nargs='*')
    ap.add_argument('--all', action='store_true')
    ap.add_argument('--scale', type=float, default=3)
    ap.add_argument('--crop', type=int, nargs=4)
    ap.add_argument('--data', default=DATA)
    a = ap.parse_args()
    DATA = a.data
    names = ([os.path.splitext(os.path.basename(p))[0] for p in sorted(glob.glob(os.path.join(DATA, 'rough', '*.txt')))]
             if a.all else a.name)
    if a.cmd in ('sheet', 'oversheet'):
        # Up to four images side by side, titled, for labelling or checking in one view.
        tiles = [grid(n, a.scale, None, write=False)
                 if a.cmd == 'sheet' or not os.path.exists(os.path.join(DATA, 'labels', n + '.txt'))
                 else overlay(n, a.scale, write=False) for n in names[:4]]
        for t, n in zip(tiles, names):
            cv2.putText(t, n[-18:], (60, t.shape[0] - 8), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (0, 0, 255), 2)
        while len(tiles) < 4:
            tiles.append(np.zeros_like(tiles[0]))
        out = f'/tmp/label_{a.cmd}.png'
        cv2.imwrite(out, np.vstack([np.hstack(tiles[:2]), np.hstack(tiles[2:])]))
        print(out)
        return
    for n in names:
        if a.cmd == 'grid':
            grid(n, a.scale, a.crop)
        elif a.cmd == 'snap':
            snap(n)
        elif a.cmd == 'ridge':
            ridge(n)
        else:
            overlay(n, a.scale)


if __name__ == '__main__':
    main()
