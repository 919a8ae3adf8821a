#!/usr/bin/env python3
# Per-frame photometric perturbation of the real captures (seeded): exposure gain U(0.6, 1.4),
# white balance r, b x U(0.85, 1.15), and in 30 % of frames a motion blur (box of 5-9 px along
# a random axis). Writes OUT (default target/realdata-perturbed)/<capture>
# laid out as ../shared/realdata; measure with REALDATA_DIR=OUT scripts/measure_realdata.py.
# `pert` is also what scripts/measure_sim_captures.py --perturb applies to its captures.
# Needs numpy and pillow. Usage: scripts/perturb_realdata.py [OUT]
import numpy as np, os, glob, shutil
from PIL import Image, ImageFilter
import sys
ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
R = os.environ.get('REALDATA_DIR', os.path.join(ROOT, '..', 'shared', 'realdata'))
O = sys.argv[1] if len(sys.argv) > 1 and __name__ == '__main__' else os.path.join(ROOT, 'target', 'realdata-perturbed')
def pert(src, dst, rng):
    im = np.asarray(Image.open(src).convert('RGB')).astype(np.float32)
    g = rng.uniform(0.6, 1.4); wr = rng.uniform(0.85, 1.15); wb = rng.uniform(0.85, 1.15)
    im = im * g * np.array([wr, 1.0, wb], np.float32)
    im = np.clip(im, 0, 255).astype(np.uint8)
    if rng.uniform() < 0.3:
        n = int(rng.integers(5, 10)); axis = int(rng.integers(0, 2))
        k = np.ones(n, np.float32) / n
        f = im.astype(np.float32)
        f = np.apply_along_axis(lambda v: np.convolve(v, k, mode='same'), axis, f)
        im = np.clip(f, 0, 255).astype(np.uint8)
    os.makedirs(os.path.dirname(dst), exist_ok=True)
    if dst.endswith('.jpg'): Image.fromarray(im).save(dst, quality=95)
    else: Image.fromarray(im).save(dst)
def main():
    # One generator through the captures in this order: the copies are the same run after run.
    rng = np.random.default_rng(0)
    os.makedirs(O + '/fruit', exist_ok=True)
    shutil.copy(R + '/fruit/transforms.json', O + '/fruit/')
    for f in sorted(glob.glob(R + '/fruit/newfruit_small/*.jpg')): pert(f, O + '/fruit/newfruit_small/' + os.path.basename(f), rng)
    os.makedirs(O + '/milk', exist_ok=True)
    shutil.copy(R + '/milk/poses_bounds.npy', O + '/milk/')
    for f in sorted(glob.glob(R + '/milk/images/*.jpg')): pert(f, O + '/milk/images/' + os.path.basename(f), rng)
    os.makedirs(O + '/dtu-scan24', exist_ok=True)
    shutil.copy(R + '/dtu-scan24/cameras.npz', O + '/dtu-scan24/')
    for f in sorted(glob.glob(R + '/dtu-scan24/*.png')): pert(f, O + '/dtu-scan24/' + os.path.basename(f), rng)
    print('done')


if __name__ == '__main__':
    main()
