#!/usr/bin/python3
"""Builds data/real/images from data/real/sources.txt.

Each line of sources.txt: <owner/repo> <commit> <path> <crop_top_px>. The photograph is read
from a local git snapshot of the repository (--mirror DIR: a bare repository or work tree of
it), the 4:3 window of full width starting at crop_top_px is cut out (the field part of the
portrait fisheye frames) and resized to 320x240 with area averaging, then written as JPEG q90
named <date>_<robot>_<file stem>.jpg. SOURCES.md is regenerated alongside.

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


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument('--mirror', required=True, help='git directory of the source repository snapshot')
    ap.add_argument('--data', default='data/real')
    a = ap.parse_args()
    src = os.path.join(a.data, 'sources.txt')
    rows = []
    with open(src) as f:
        for ln, line in enumerate(f, 1):
            line = line.strip()
            if not line or line.startswith('#'):
                continue
            fields = line.split()
            if len(fields) != 4:
                sys.exit(f'{src}:{ln}: expected 4 fields (repo commit path crop_top), got {len(fields)}')
            repo, commit, path, top = fields
            blob = subprocess.run(['git', '--git-dir', a.mirror, 'show', f'{commit}:{path}'], capture_output=True)
            if blob.returncode != 0:
                sys.exit(f'{src}:{ln}: {path} not found at {commit} in {a.mirror}')
            img = cv2.imdecode(np.frombuffer(blob.stdout, np.uint8), cv2.IMREAD_COLOR)
            if img is None:
                sys.exit(f'{src}:{ln}: {path}: not a readable image')
            h, w = img.shape[:2]
            top = int(top)
            ch = w * OUT_H // OUT_W
            if top < 0 or top + ch > h:
                sys.exit(f'{src}:{ln}: crop_top {top} + {ch} rows exceeds the image height {h}')
            out = cv2.resize(img[top:top + ch, :], (OUT_W, OUT_H), interpolation=cv2.INTER_AREA)
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
        f.write('Derivation (tools/label/prepare.py): the full-width 4:3 window starting at row `crop_top` '
                '(608x456 px) resized to 320x240 (area averaging), JPEG quality 90.\n\n')
        f.write('| image | repository | path | commit | crop_top | licence |\n|---|---|---|---|---|---|\n')
        for name, repo, path, commit, w, h, top, ch in rows:
            f.write(f'| {name} | {repo} | {path} | {commit[:12]} | {top} | Apache-2.0 |\n')
    os.replace(md + '.tmp', md)
    print(f'{len(rows)} images written to {a.data}/images')


if __name__ == '__main__':
    main()
