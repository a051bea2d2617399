"""Benchmarks: softvr against the libraries a user would otherwise reach for.

``softvr bench volume`` (:mod:`softvr.bench.volume`) reproduces thesis Figs 3.5 and 3.6 and
runs softvr head to head with VTK + SciPy and SimpleITK (:mod:`softvr.bench._volume_peers`).
``softvr bench contact`` (:mod:`softvr.bench.contact`) drops a soft cube on a plane in softvr,
MuJoCo, PyBullet and Newton (:mod:`softvr.bench._contact_peers`) and runs the thesis' candy
scene; ``softvr bench adhesion`` (:mod:`softvr.bench.adhesion`) runs that scene with and
without adhesion (thesis Fig. 4.4).
"""
