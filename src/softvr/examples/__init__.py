"""Runnable examples, one ``example_<topic>.py`` each with an ``Example`` class
(``__init__`` / ``step`` / ``render``) and a ``main(argv)``; kernel examples take ``--device``.
``softvr demo`` runs the volume example, ``softvr run SCENE`` the physics ones."""
