"""The viewer's mouse tool: grab a body where the mouse points and pull it with a spring.

Right button (or control + left) picks the surface point under the mouse, finds the body it
belongs to (a deformable body's nearest node, or the rigid body that holds the point) and,
while the button is held, applies ``F = k (target - point)`` to it through
:attr:`softvr.Scene.external`: the target follows the mouse in the plane through the grabbed
point facing the camera; ``k`` is ``stiffness`` [1/s^2] times the body's mass, so every body
follows about equally fast. Releasing the button removes the force.
"""

from __future__ import annotations

import numpy as np

__all__ = ["DragTool"]


class DragTool:
    """Mouse spring on the bodies of ``scene`` drawn by ``vtk_renderer`` (module docstring)."""

    def __init__(self, scene, vtk_renderer, *, stiffness: float = 400.0):
        self.scene, self.renderer, self.stiffness = scene, vtk_renderer, float(stiffness)
        self.grab: tuple | None = None  # (body index, node index or local point [3], depth in display z)
        self.target: np.ndarray | None = None

    # ------------------------------------------------------------------ picking
    def _world(self, x: float, y: float, depth: float) -> np.ndarray:
        self.renderer.SetDisplayPoint(float(x), float(y), float(depth))
        self.renderer.DisplayToWorld()
        w = self.renderer.GetWorldPoint()
        return np.array(w[:3]) / (w[3] if w[3] else 1.0)

    def press(self, x: int, y: int) -> bool:
        """Grab the body under display position (x, y); False when nothing is there."""
        from vtkmodules.vtkRenderingCore import vtkCellPicker  # noqa: PLC0415

        picker = vtkCellPicker()
        picker.SetTolerance(0.002)
        if not picker.Pick(x, y, 0, self.renderer):
            return False
        p = np.array(picker.GetPickPosition())
        best = None
        for i, body in enumerate(self.scene.bodies):
            if body.infinite_mass:
                continue
            if hasattr(body, "q"):
                node = int(np.argmin(np.linalg.norm(body.q - p, axis=1)))
                d = float(np.linalg.norm(body.q[node] - p))
                grip = node
            else:
                d = max(float(np.linalg.norm(p - body.position)) - body.extent, 0.0)
                grip = (p - body.position) @ body.rotation  # the point in the body's frame
            if best is None or d < best[0]:
                best = (d, i, grip)
        if best is None:
            return False
        self.renderer.SetWorldPoint(*p, 1.0)
        self.renderer.WorldToDisplay()
        self.grab = (best[1], best[2], self.renderer.GetDisplayPoint()[2])
        self.target = p
        return True

    def move(self, x: int, y: int) -> None:
        if self.grab is not None:
            self.target = self._world(x, y, self.grab[2])

    def release(self) -> None:
        if self.grab is not None:
            self.scene.external.pop(self.grab[0], None)
        self.grab = self.target = None

    # ------------------------------------------------------------------ forces
    def point(self) -> np.ndarray | None:
        """The grabbed point now [3] [m]."""
        if self.grab is None:
            return None
        body = self.scene.bodies[self.grab[0]]
        if hasattr(body, "q"):
            return body.q[self.grab[1]].copy()
        return body.position + body.rotation @ self.grab[1]

    def apply(self) -> None:
        """Set this step's spring force on the grabbed body (call before every step)."""
        if self.grab is None:
            return
        index, grip, _ = self.grab
        assert self.target is not None  # set with grab
        body = self.scene.bodies[index]
        mass = float(np.sum(body.mass))
        force = self.stiffness * mass * (self.target - self.point())
        if hasattr(body, "q"):
            f = np.zeros_like(body.q)
            f[grip] = force
        else:
            arm = body.rotation @ grip
            f = np.concatenate([force, np.cross(arm, force)])
        self.scene.external[index] = f
