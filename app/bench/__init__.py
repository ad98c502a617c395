"""`panogrf bench`: every method and setting on one chart, a baseline sweep, the hard cases.

- `settings`: the methods and settings charted, one render function for all of them;
- `cases`: scenes from the synthetic generator built to be hard (occlusion, textureless walls,
  poles, off the line, extrapolation, a pose at a source) and the baseline sweep's scenes;
- `frontier`: the Pareto frontier and the charts;
- `run`: the benchmark itself (quality, time at 512 x 1024, memory) and its table.
"""
