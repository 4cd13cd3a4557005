"""BC7 mode 7 (two subsets, one of 64 shapes) and the per-block choice of modes 6 and 7: issue 29
measured them and did not adopt them for training (docs/benchmarks.md, "Partitioned BC7 modes,
trained"), so they live beside the benchmarks that measure them (bound_t0.py), not in the package.
Import with benchmarks/ on sys.path: ``from bc7_mode7 import encode7, mode7, modes``. The shapes
(`bcfpipe.bptc`) stay in the package: its any-mode decoder reads mode 7."""
