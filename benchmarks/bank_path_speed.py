"""The default user path (no truth: init from sensors, a bank of 8 yaw hypotheses) through ia.align on a 300-s car,
with earth.ecef_to_geodetic as the closed form (default) and as pymap3d, same run, best of 2 (docs/results.md).

    .venv/bin/python benchmarks/bank_path_speed.py
"""
import sys
import time

import numpy as np
import pymap3d

sys.path.insert(0, __file__.rsplit('/benchmarks/', 1)[0])
import insalign_ros as ia
from insalign_ros.core import earth
d = ia.simulate("car", seed=4, duration_s=300.0)
fast = earth.ecef_to_geodetic
def lib(p_e):
    lat, lon, h = pymap3d.ecef2geodetic(p_e[0], p_e[1], p_e[2], deg=False)
    return float(lat), float(lon), float(h)
res = {}
for rep in range(2):
    for name, fn in (("pymap3d", lib), ("closed form", fast)):
        earth.ecef_to_geodetic = fn
        t = time.perf_counter(); r = ia.align(d); el = time.perf_counter() - t
        res.setdefault(name, []).append((el, r.rpy_deg[-1]))
for k, v in res.items():
    print(f"{k}: ia.align car 300 s, sensors init (yaw bank of 8): best {min(x[0] for x in v):.2f} s = {d.n / min(x[0] for x in v):,.0f} samples/s; final rpy {v[-1][1]}")
print("max final rpy diff", np.max(np.abs(res['pymap3d'][-1][1] - res['closed form'][-1][1])))
