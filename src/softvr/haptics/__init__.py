"""Haptic interaction: devices, the 1 kHz haptic loop and the virtual-coupling tool (thesis 5.4).

* :class:`HapticDevice` is the plug-in point for devices; :class:`ScriptedDevice` follows a
  path, :class:`MouseDevice` is moved by the viewer.
* :class:`HapticLoop` reads the device and sends it forces at 1 kHz in its own thread, from
  the linearized :class:`HandleModel` the simulation publishes after each step (multi-rate,
  after [GO09]).
* :class:`HapticTool` ties a simulated tool to the device's handle by an implicit zero-length
  spring (a :class:`~softvr.dynamics.Coupling`) and publishes the handle model.

Forces are in N, positions in m, rates in Hz.

Examples
--------
>>> import numpy as np
>>> from softvr import Scene
>>> from softvr.collision import Plane
>>> from softvr.dynamics import RigidBody
>>> from softvr.haptics import HapticLoop, HapticTool, MouseDevice
>>> hand = MouseDevice(position=(0.0, 0.0, 0.0))  # 1 cm below where a 1 cm ball rests
>>> scene = Scene()
>>> scene.add_plane(Plane())
>>> finger = RigidBody.sphere(0.01, 1000.0, position=(0.0, 0.0, 0.01))
>>> _ = scene.add_body(finger, collision_sphere=0.01)
>>> loop = HapticLoop(hand)
>>> tool = HapticTool(scene, finger, loop, stiffness=200.0, damping=1.0)
>>> for _ in range(50):
...     _ = tool.publish(scene.step(0.005))
>>> np.round(loop.tick(), 2)  # the spring stretched 1 cm: 2 N up on the hand
array([0., 0., 2.])
"""

from softvr.haptics.devices import HapticDevice, MouseDevice, ScriptedDevice
from softvr.haptics.loop import HandleModel, HapticLoop
from softvr.haptics.tool import HapticTool

__all__ = ["HandleModel", "HapticDevice", "HapticLoop", "HapticTool", "MouseDevice", "ScriptedDevice"]
