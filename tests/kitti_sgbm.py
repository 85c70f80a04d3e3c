"""OpenCV SGBM's disparities at given pixels of a rectified pair (tests/kitti.rs).

Usage: kitti_sgbm.py LEFT RIGHT [ROWS] < "x y" lines; prints one disparity per line (px; <= 0
where SGBM found no unique match). ROWS: the right image's row correction, as flyd applies
it (rectification.right_row_offset_px: row y shows row y + ROWS, linear interpolation). SGBM as the KITTI reference figures were measured: 3-way, 5x5
blocks, 128 disparities, P1 = 8*25, P2 = 32*25, uniquenessRatio 10.
"""
import sys

import cv2
import numpy as np

left = cv2.imread(sys.argv[1], cv2.IMREAD_GRAYSCALE)
right = cv2.imread(sys.argv[2], cv2.IMREAD_GRAYSCALE)
if left is None or right is None:
    sys.exit(f"cannot read {sys.argv[1]} or {sys.argv[2]}")
rows = float(sys.argv[3]) if len(sys.argv) > 3 else 0.0
if rows != 0.0:
    shift = np.float32([[1, 0, 0], [0, 1, rows]])
    right = cv2.warpAffine(
        right,
        shift,
        (right.shape[1], right.shape[0]),
        flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
        borderMode=cv2.BORDER_REPLICATE,
    )
sgbm = cv2.StereoSGBM_create(
    minDisparity=0,
    numDisparities=128,
    blockSize=5,
    P1=8 * 25,
    P2=32 * 25,
    uniquenessRatio=10,
    mode=cv2.STEREO_SGBM_MODE_SGBM_3WAY,
)
disparity = sgbm.compute(left, right).astype(np.float32) / 16.0
h, w = disparity.shape
for line in sys.stdin:
    x, y = (int(v) for v in line.split())
    print(disparity[y, x] if 0 <= x < w and 0 <= y < h else -1.0)
