"""The soft cube every engine of ``softvr bench contact`` drops (softvr and the peers in
:mod:`softvr.bench._contact_peers` alike): its size, cells, material and step, and its mesh."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from softvr.volume import Volume, grid_tet_mesh

__all__ = ["FULL_SCENE", "QUICK_SCENE", "CubeScene", "cube_mesh"]


@dataclass(frozen=True)
class CubeScene:
    """A soft cube of ``cells^3`` grid cells, its bottom face ``drop`` above the plane z = 0.

    Attributes
    ----------
    size : float [m]
        Cube edge; the cube spans x, y in [-size/2, size/2].
    cells : int
        Grid cells per edge (5 tets per cell in softvr, PyBullet and Newton; 6 in MuJoCo).
    drop : float [m]
        Initial height of the bottom face.
    duration : float [s]
        Simulated time.
    dt : float [s]
    density : float [kg/m^3]
    young : float [Pa]
    poisson : float
    friction : float
        Coulomb coefficient of the cube-plane contacts.
    gravity : float [m/s^2]
        Along -z.
    """

    size: float = 0.8
    cells: int = 8
    drop: float = 0.5
    duration: float = 1.0
    dt: float = 1.0 / 60.0
    density: float = 1000.0
    young: float = 2.5e5
    poisson: float = 0.25
    friction: float = 0.5
    gravity: float = 9.81

    @property
    def steps(self) -> int:
        return int(round(self.duration / self.dt))

    @property
    def mass(self) -> float:
        return self.density * self.size**3

    @property
    def lame(self) -> tuple[float, float]:
        """(lambda, mu) [Pa]."""
        e, nu = self.young, self.poisson
        return e * nu / ((1 + nu) * (1 - 2 * nu)), e / (2 * (1 + nu))

    def describe(self) -> str:
        lam, mu = self.lame
        return (f"{self.size:g} m cube, {self.cells}^3 cells, bottom {self.drop:g} m above the plane, "
                f"dt 1/{1 / self.dt:.0f} s, {self.duration:g} s ({self.steps} steps), friction {self.friction:g}, "
                f"density {self.density:g}, E {self.young:.3g} Pa, nu {self.poisson:g} (mu = {mu:.3g}, lambda = {lam:.3g})")


FULL_SCENE = CubeScene()
QUICK_SCENE = CubeScene(size=0.2, cells=3, drop=0.05, duration=0.25)


def cube_mesh(scene: CubeScene, drop: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Nodes [m] and 5-per-cell tets of the cube (:func:`softvr.volume.grid_tet_mesh`)."""
    c = scene.cells
    spacing = np.full(3, scene.size / c)
    corner = np.array([-scene.size / 2, -scene.size / 2, scene.drop if drop is None else drop])
    return grid_tet_mesh(Volume(np.zeros((c, c, c), np.uint8), spacing=spacing, origin=spacing / 2 + corner), c)
