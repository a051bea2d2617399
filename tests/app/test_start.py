"""A built scene starts nothing until it plays: ``softvr check`` builds a scene with a haptic
tool in its own process and checks its start without starting that process; the first frame
starts it, once."""

from softvr.cli import main
from softvr.haptics import HapticLoop
from softvr.scene import load_scene

SCENE = """format = "softvr-scene 1"
[simulation]
dt = 0.01
frames = 2
[material.finger]
density = 1000.0
[[plane]]
point = [0.0, 0.0, 0.0]
normal = [0.0, 0.0, 1.0]
[[body]]
name = "finger"
type = "tool"
sphere = 0.01
material = "finger"
position = [0.0, 0.0, 0.1]
stiffness = 300.0
haptics = true
[body.motion]
times = [0.0, 1.0]
positions = [[0.0, 0.0, 0.1], [0.0, 0.0, 0.05]]
"""


def test_check_starts_no_haptic_process_and_the_first_frame_starts_it(tmp_path, monkeypatch, capsys):
    started = []
    # Counted, not run: the contract is when the process is asked for, not the process itself.
    monkeypatch.setattr(HapticLoop, "start", lambda loop: started.append(loop) or loop)
    path = tmp_path / "finger.toml"
    path.write_text(SCENE)
    assert main(["check", str(path)]) == 0, capsys.readouterr().err
    assert "ok" in capsys.readouterr().out and started == []
    with load_scene(path) as player:
        assert started == []
        player.step()
        player.step()
        assert len(started) == 1
