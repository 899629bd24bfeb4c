"""Benchmark side of the calibration twin: the synthetic IRB-1200 problem, the noise-floor reference fit,
adapters that drive the peer calibrators (FIGAROH, pybotics, robotkinecal) through their own APIs, and the
writers of ``results/benchmark.json`` / ``results/benchmark_table.md``.

This is experiment code, not library code: it reads the truth of the synthetic problem (to score every method
against it and to compute the floor), so nothing here may ever be imported by ``twin/``.
"""
