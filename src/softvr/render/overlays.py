"""What a live viewer draws over a simulation: a status line, contact points with their forces,
line sets (tet edges). Plain arrays in, VTK actors out; each overlay can be shown or hidden.
"""

from __future__ import annotations

import numpy as np

__all__ = ["ContactOverlay", "LineOverlay", "TextOverlay"]


class TextOverlay:
    """A line of text in the window's top-left corner (frame, FPS, ms per stage)."""

    def __init__(self, renderer):
        from vtkmodules.vtkRenderingCore import vtkTextActor  # noqa: PLC0415

        self.actor = vtkTextActor()
        prop = self.actor.GetTextProperty()
        prop.SetFontSize(14)
        prop.SetColor(1.0, 1.0, 0.85)
        self.actor.SetDisplayPosition(8, 8)
        renderer.AddViewProp(self.actor)

    def set(self, text: str) -> None:
        self.actor.SetInput(text)


class LineOverlay:
    """Line segments between points (e.g. tet edges): ``update(points [n, 3] [m])`` with fixed
    ``edges`` [e, 2]."""

    def __init__(self, renderer, edges, color=(0.9, 0.9, 0.3)):
        from vtkmodules.vtkCommonCore import vtkPoints  # noqa: PLC0415
        from vtkmodules.vtkCommonDataModel import vtkCellArray, vtkPolyData  # noqa: PLC0415
        from vtkmodules.vtkRenderingCore import vtkActor, vtkPolyDataMapper  # noqa: PLC0415
        from vtkmodules.util.numpy_support import numpy_to_vtkIdTypeArray  # noqa: PLC0415

        self.points = vtkPoints()
        self.poly = vtkPolyData()
        self.poly.SetPoints(self.points)
        e = np.asarray(edges, np.int64)
        cells = vtkCellArray()
        cells.SetData(numpy_to_vtkIdTypeArray(np.arange(0, 2 * len(e) + 1, 2, dtype=np.int64), deep=True),
                      numpy_to_vtkIdTypeArray(e.ravel(), deep=True))
        self.poly.SetLines(cells)
        mapper = vtkPolyDataMapper()
        mapper.SetInputData(self.poly)
        self.actor = vtkActor()
        self.actor.SetMapper(mapper)
        self.actor.GetProperty().SetColor(*color)
        renderer.AddActor(self.actor)

    def update(self, points) -> None:
        from vtkmodules.util.numpy_support import numpy_to_vtk  # noqa: PLC0415

        self.points.SetData(numpy_to_vtk(np.ascontiguousarray(points, dtype=np.float64), deep=True))
        self.poly.Modified()

    def show(self, visible: bool) -> None:
        self.actor.SetVisibility(bool(visible))


class ContactOverlay:
    """Contact points with a line along each normal, as long as ``scale`` [m/N] times the
    force [N], coloured by a value in [0, 1] (adhesion intensity: blue 0 -> red 1) or white."""

    def __init__(self, renderer, scale: float = 0.01):
        from vtkmodules.vtkCommonCore import vtkPoints, vtkUnsignedCharArray  # noqa: PLC0415
        from vtkmodules.vtkCommonDataModel import vtkCellArray, vtkPolyData  # noqa: PLC0415
        from vtkmodules.vtkRenderingCore import vtkActor, vtkPolyDataMapper  # noqa: PLC0415

        self.scale = float(scale)
        self.points, self.lines, self.colors = vtkPoints(), vtkCellArray(), vtkUnsignedCharArray()
        self.colors.SetNumberOfComponents(3)
        self.poly = vtkPolyData()
        self.poly.SetPoints(self.points)
        self.poly.SetLines(self.lines)
        self.poly.SetVerts(vtkCellArray())
        self.poly.GetCellData().SetScalars(self.colors)
        mapper = vtkPolyDataMapper()
        mapper.SetInputData(self.poly)
        self.actor = vtkActor()
        self.actor.SetMapper(mapper)
        self.actor.GetProperty().SetLineWidth(2.0)
        self.actor.GetProperty().SetPointSize(5.0)
        renderer.AddActor(self.actor)

    def update(self, points, normals, forces, values=None) -> None:
        """``points`` [k, 3] [m], unit ``normals`` [k, 3], normal ``forces`` [k] [N], optional
        ``values`` [k] in [0, 1] for the colour."""
        from vtkmodules.util.numpy_support import numpy_to_vtk, numpy_to_vtkIdTypeArray  # noqa: PLC0415
        from vtkmodules.vtkCommonDataModel import vtkCellArray  # noqa: PLC0415

        p = np.asarray(points, float).reshape(-1, 3)
        k = len(p)
        tips = p + np.asarray(normals, float).reshape(-1, 3) * (self.scale * np.asarray(forces, float))[:, None]
        self.points.SetData(numpy_to_vtk(np.ascontiguousarray(np.vstack([p, tips])), deep=True))
        verts, lines = vtkCellArray(), vtkCellArray()
        verts.SetData(numpy_to_vtkIdTypeArray(np.arange(k + 1, dtype=np.int64), deep=True),
                      numpy_to_vtkIdTypeArray(np.arange(k, dtype=np.int64), deep=True))
        pairs = np.c_[np.arange(k), np.arange(k) + k].astype(np.int64)
        lines.SetData(numpy_to_vtkIdTypeArray(np.arange(0, 2 * k + 1, 2, dtype=np.int64), deep=True),
                      numpy_to_vtkIdTypeArray(pairs.ravel(), deep=True))
        self.poly.SetVerts(verts)
        self.poly.SetLines(lines)
        v = np.ones(k) if values is None else np.clip(np.asarray(values, float), 0.0, 1.0)
        rgb = np.c_[255 * v, 80 + 0 * v, 255 * (1 - v)] if values is not None else np.full((k, 3), 240.0)
        colors = np.vstack([rgb, rgb]).astype(np.uint8)  # one per vertex cell, one per line
        self.poly.GetCellData().SetScalars(numpy_to_vtk(colors, deep=True))
        self.poly.Modified()

    def show(self, visible: bool) -> None:
        self.actor.SetVisibility(bool(visible))
