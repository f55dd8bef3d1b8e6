"""Benchmark sweeps (``mitsnerf bench``): every (scene, method, seed) cell of a ``benchmarks/*.toml``.

- :mod:`~mitsnerf.bench.config`: the TOML configs as validated dataclasses (``--quick`` profile);
- :mod:`~mitsnerf.bench.cells`: resolved, hashed cells and their results on disk (resume);
- :mod:`~mitsnerf.bench.worker`: one cell: ``mitsnerf.runs.fit.fit`` (scored by :mod:`mitsnerf.scoring`) with a
  held-out PSNR curve indexed by steps, and the seconds to reach target PSNRs;
- :mod:`~mitsnerf.bench.executors`: sequential, process pool, Ray;
- :mod:`~mitsnerf.bench.runner`: plan, skip, generate, run, write the outputs;
- :mod:`~mitsnerf.bench.tables`, :mod:`~mitsnerf.bench.plots`, :mod:`~mitsnerf.bench.report`: the outputs.
"""
