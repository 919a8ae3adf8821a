#!/usr/bin/env python3
"""Compute the milk-carton rectangles from the RGBA cut-out masks.

Run (needs numpy and pillow):
    python3 mask_rects.py [MILK_DIR] > labels.csv
MILK_DIR defaults to /work/shared/realdata/milk (the folder holding images/ and images_mask/).

For every images/<n>.jpg (1140 x 855) it reads images_mask/<n>-removebg-preview.png (577 x 433),
takes the pixels with alpha > 128, their bounding box in mask pixels, scales it to image pixels
(x by 1140/577, y by 855/433) rounding outward, clips to the image, and prints one CSV row
`image,x,y,width,height,object` with object `milk`, after a header line. Rows in numeric file order.
"""
import math
import os
import sys

import numpy as np
from PIL import Image

def main():
    d = sys.argv[1] if len(sys.argv) > 1 else "/work/shared/realdata/milk"
    names = sorted((f for f in os.listdir(os.path.join(d, "images")) if f.endswith(".jpg")),
                   key=lambda f: int(f[:-4]))
    print("image,x,y,width,height,object")
    for f in names:
        n = f[:-4]
        W, H = Image.open(os.path.join(d, "images", f)).size
        m = Image.open(os.path.join(d, "images_mask", n + "-removebg-preview.png")).convert("RGBA")
        a = np.asarray(m)[:, :, 3]
        mh, mw = a.shape
        ys, xs = np.nonzero(a > 128)
        if len(xs) == 0:
            continue
        sx, sy = W / mw, H / mh
        # mask pixel i covers image columns [i*sx, (i+1)*sx)
        x0 = max(0, math.floor(xs.min() * sx))
        y0 = max(0, math.floor(ys.min() * sy))
        x1 = min(W, math.ceil((xs.max() + 1) * sx))  # exclusive
        y1 = min(H, math.ceil((ys.max() + 1) * sy))
        print(f"{f},{x0},{y0},{x1 - x0},{y1 - y0},milk")

if __name__ == "__main__":
    main()
