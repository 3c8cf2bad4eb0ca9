#!/usr/bin/python3
"""Plumb-line calibration of the real set's fisheye lens (one-parameter division model).

Markings that are straight on the field are imaged bent by the lens. Along each rough polyline
of data/real/lens_lines.txt the stripe centre is found on the full-resolution original every
2 px (luma profile across the polyline, strongest rising and falling derivative, their
midpoint), and k of the division model

    p_u = c + (p_d - c) / (1 + k |p_d - c|^2 / R^2),    c = image centre, R = 400 px

is the value that makes the undistorted samples of every line most nearly collinear (least
squares of the total-least-squares line residuals, golden-section search). Prints k and the
rms / max residual before and after; prepare.py undistorts with it.

    tools/label/lens.py --mirror /path/to/robocup_ml.git [--data data/real]
"""
import argparse
import os
import subprocess
import sys

import cv2
import numpy as np

R_NORM = 400.0


def undistort_pts(p, c, k):
    d = p - c
    r2 = (d ** 2).sum(axis=1) / R_NORM ** 2
    return c + d / (1.0 + k * r2)[:, None]


def distort_pts(p, c, k):
    """Inverse of undistort_pts: r_d from r_u = r_d / (1 + k r_d^2 / R^2)."""
    d = p - c
    ru = np.sqrt((d ** 2).sum(axis=-1)) / R_NORM
    with np.errstate(divide='ignore', invalid='ignore'):
        rd = np.where(np.abs(k * ru) < 1e-12, ru, (1 - np.sqrt(np.maximum(0.0, 1 - 4 * k * ru ** 2))) / (2 * k * ru))
        scale = np.where(ru > 1e-12, rd / ru, 1.0)
    return c + d * scale[..., None]


def line_residuals(pts):
    cc = np.median(pts, axis=0)
    _, _, vt = np.linalg.svd(pts - cc)
    n = np.array([-vt[0][1], vt[0][0]])
    return (pts - cc) @ n


def stripe_centres(lum, poly):
    out = []
    for a, b in zip(poly[:-1], poly[1:]):
        L = np.linalg.norm(b - a)
        u = (b - a) / L
        n = np.array([-u[1], u[0]])
        ss = np.arange(-14.0, 14.0 + 1e-9, 0.25)
        for t in np.arange(0.0, L, 2.0):
            q = a + t * u
            xs, ys = q[0] + ss * n[0], q[1] + ss * n[1]
            if xs.min() < 1 or ys.min() < 1 or xs.max() > lum.shape[1] - 2 or ys.max() > lum.shape[0] - 2:
                continue
            prof = cv2.remap(lum, xs.astype(np.float32)[None, :], ys.astype(np.float32)[None, :], cv2.INTER_LINEAR)[0]
            prof = np.convolve(prof, np.ones(5) / 5, mode='same')
            d = np.gradient(prof)[3:-3]
            ip, im = int(np.argmax(d)), int(np.argmin(d))
            if ip < im and d[ip] > 1.0 and d[im] < -1.0:
                s = ss[3 + (ip + im) // 2] if (ip + im) % 2 == 0 else 0.5 * (ss[3 + ip] + ss[3 + im])
                out.append(q + s * n)
    return np.array(out)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument('--mirror', required=True)
    ap.add_argument('--data', default='data/real')
    a = ap.parse_args()
    lines, c = [], None
    path = os.path.join(a.data, 'lens_lines.txt')
    with open(path) as f:
        for ln, line in enumerate(f, 1):
            t = line.split('#')[0].split()
            if not t:
                continue
            if len(t) < 7 or len(t) % 2 == 0:
                sys.exit(f'{path}:{ln}: expected commit path crop_top and at least two x y points')
            commit, p, top = t[0], t[1], t[2]
            t = t[2:]
            blob = subprocess.run(['git', '--git-dir', a.mirror, 'show', f'{commit}:{p}'], capture_output=True).stdout
            img = cv2.imdecode(np.frombuffer(blob, np.uint8), cv2.IMREAD_COLOR)
            if img is None:
                sys.exit(f'{path}:{ln}: cannot read {p}')
            h, w = img.shape[:2]
            c = np.array([(w - 1) / 2.0, (h - 1) / 2.0])
            s = w / 320.0
            poly = np.array([float(v) for v in t[1:]]).reshape(-1, 2) * s + np.array([0.0, float(top)])
            lum = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY).astype(np.float32)
            pts = stripe_centres(lum, poly)
            if len(pts) < 10:
                print(f'{path}:{ln}: skipped, too few stripe samples ({len(pts)})')
                continue
            lines.append(pts)
    # Robust: residuals beyond 4 px (a wrong edge picked by the profile) count as 4 px.
    cost = lambda k: sum(float(np.minimum(line_residuals(undistort_pts(p, c, k)) ** 2, 16.0).sum()) for p in lines)
    ks = np.linspace(-0.9, 0.9, 181)
    k0 = ks[int(np.argmin([cost(k) for k in ks]))]
    lo, hi = k0 - 0.01, k0 + 0.01
    g = (np.sqrt(5) - 1) / 2
    for _ in range(80):
        m1, m2 = hi - g * (hi - lo), lo + g * (hi - lo)
        if cost(m1) < cost(m2):
            hi = m2
        else:
            lo = m1
    k = 0.5 * (lo + hi)
    for kk, what in ((0.0, 'distorted'), (k, 'undistorted')):
        res = np.concatenate([line_residuals(undistort_pts(p, c, kk)) for p in lines])
        inl = np.abs(res) <= 4.0
        print(f'{what}: rms {np.sqrt(np.mean(res[inl] ** 2)):.2f} px of {inl.sum()} samples within 4 px '
              f'(of {len(res)}, {len(lines)} lines)')
    for p in lines:
        r = line_residuals(undistort_pts(p, c, k))
        inl = np.abs(r) <= 4.0
        print(f'  line rms {np.sqrt(np.mean(r[inl] ** 2)):.2f} px, {inl.sum()} of {len(r)} samples within 4 px')
    print(f'k = {k:.5f}')


if __name__ == '__main__':
    main()
