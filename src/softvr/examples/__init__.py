"""Leaf scripts, one ``example_<topic>.py`` per demo, each loading its bundled scene file (the
demo's one definition, :data:`softvr.scene.BUNDLED`) through the public API and playing it: a
window, or ``--headless`` to files (``--frames``, ``--size``, ``--device``: the flags they share,
``_leaf.play_leaf``). ``run`` is the
registry of ``softvr run / view / demo NAME``;
``shoulder_anatomy`` makes the bundled shoulder meshes and parts files."""
