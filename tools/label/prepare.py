#!/usr/bin/python3
"""Builds data/real/images from data/real/sources.txt.

Each line of sources.txt: <owner/repo> <commit> <path> <view_centre_y>. The photograph is read
from a local git snapshot of the repository (--mirror DIR: a bare repository or work tree of
it) and its fisheye distortion removed with the division model of data/real/lens.txt (fitted
by tools/label/lens.py): the output is a 320x240 pinhole view, `scale` undistorted px per
output px, centred horizontally and on undistorted row view_centre_y (the field part of the
portrait frames). The original is blurred first (Gaussian, sigma 0.4 scale) against aliasing,
then sampled bilinearly. Written as JPEG q90 named <date>_<robot>_<file stem>.jpg;
SOURCES.md is regenerated alongside.

    tools/label/prepare.py --mirror /path/to/robocup_ml.git [--data data/real]
"""
import argparse
import os
import subprocess
import sys

import cv2
import numpy as np

OUT_W, OUT_H = 320, 240


def image_name(path):
    parts = path.split('/')
    stem = os.path.splitext(parts[-1])[0]
    return '_'.join(parts[:-1] + [stem]) + '.jpg'


def read_lens(path):
    vals = {}
    with open(path) as f:
        for ln, line in enumerate(f, 1):
            t = line.split('#')[0].split()
            if not t:
                continue
            if len(t) != 2:
                sys.exit(f'{path}:{ln}: expected "name value"')
            vals[t[0]] = float(t[1])
    for key in ('k', 'r_norm', 'scale'):
        if key not in vals:
            sys.exit(f'{path}: missing {key}')
    return vals


def undistorted_view(img, lens, centre_y):
    """The 320x240 pinhole view described in the module comment."""
    h, w = img.shape[:2]
    c = np.array([(w - 1) / 2.0, (h - 1) / 2.0])
    s, k, R = lens['scale'], lens['k'], lens['r_norm']
    u, v = np.meshgrid(np.arange(OUT_W, dtype=np.float64), np.arange(OUT_H, dtype=np.float64))
    dx = (u - (OUT_W - 1) / 2.0) * s
    dy = (v - (OUT_H - 1) / 2.0) * s + (centre_y - c[1])
    ru = np.sqrt(dx ** 2 + dy ** 2) / R
    # Inverse of r_u = r_d / (1 + k r_d^2) (radii in units of R).
    with np.errstate(divide='ignore', invalid='ignore'):
        rd = np.where(np.abs(k * ru) < 1e-12, ru, (1 - np.sqrt(np.maximum(0.0, 1 - 4 * k * ru ** 2))) / (2 * k * ru))
        f = np.where(ru > 1e-12, rd / ru, 1.0)
    mx = (c[0] + dx * f).astype(np.float32)
    my = (c[1] + dy * f).astype(np.float32)
    blurred = cv2.GaussianBlur(img, (0, 0), 0.4 * s)
    return cv2.remap(blurred, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=(0, 0, 0))


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument('--mirror', required=True, help='git directory of the source repository snapshot')
    ap.add_argument('--data', default='data/real')
    a = ap.parse_args()
    src = os.path.join(a.data, 'sources.txt')
    lens = read_lens(os.path.join(a.data, 'lens.txt'))
    rows = []
    with open(src) as f:
        for ln, line in enumerate(f, 1):
            line = line.strip()
            if not line or line.startswith('#'):
                continue
            fields = line.split()
            if len(fields) != 4:
                sys.exit(f'{src}:{ln}: expected 4 fields (repo commit path view_centre_y), got {len(fields)}')
            repo, commit, path, top = fields
            blob = subprocess.run(['git', '--git-dir', a.mirror, 'show', f'{commit}:{path}'], capture_output=True)
            if blob.returncode != 0:
                sys.exit(f'{src}:{ln}: {path} not found at {commit} in {a.mirror}')
            img = cv2.imdecode(np.frombuffer(blob.stdout, np.uint8), cv2.IMREAD_COLOR)
            if img is None:
                sys.exit(f'{src}:{ln}: {path}: not a readable image')
            h, w = img.shape[:2]
            top = float(top)
            if not 0 <= top < h:
                sys.exit(f'{src}:{ln}: view_centre_y {top} outside the image height {h}')
            out = undistorted_view(img, lens, top)
            ch = 0
            name = image_name(path)
            dst = os.path.join(a.data, 'images', name)
            tmp = dst + '.tmp.jpg'
            cv2.imwrite(tmp, out, [cv2.IMWRITE_JPEG_QUALITY, 90])
            os.replace(tmp, dst)
            rows.append((name, repo, path, commit, w, h, top, ch))
    md = os.path.join(a.data, 'SOURCES.md')
    with open(md + '.tmp', 'w') as f:
        f.write('# Sources of the real-image set\n\n')
        f.write('All photographs: repository [andrepool/robocup_ml](https://github.com/andrepool/robocup_ml), '
                '"Robocup data for Machine Learning", Copyright 2019-2024 Andre Pool, '
                'SPDX-License-Identifier: Apache-2.0 (stated in its README.md). RoboCup Middle Size League '
                'fields (green carpet, white markings), fisheye robot cameras, 608x800 JPEG originals.\n\n')
        f.write('Derivation (tools/label/prepare.py): fisheye distortion removed with the division model of '
                f'lens.txt (k {lens["k"]}, fitted by tools/label/lens.py on markings straight on the field), '
                f'a 320x240 pinhole view at {lens["scale"]} undistorted px per px centred on undistorted row '
                '`view_centre_y`, JPEG quality 90.\n\n')
        f.write('| image | repository | path | commit | view_centre_y | licence |\n|---|---|---|---|---|---|\n')
        for name, repo, path, commit, w, h, top, ch in rows:
            f.write(f'| {name} | {repo} | {path} | {commit[:12]} | {top} | Apache-2.0 |\n')
    os.replace(md + '.tmp', md)
    print(f'{len(rows)} images written to {a.data}/images')


if __name__ == '__main__':
    main()
