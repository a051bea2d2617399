"""Benchmarks: softvr against the libraries a user would otherwise reach for.

``softvr bench volume`` (:mod:`softvr.bench.volume`) reproduces thesis Figs 3.5 and 3.6 and
runs softvr head to head with VTK + SciPy and SimpleITK (:mod:`softvr.bench._volume_peers`).
"""
