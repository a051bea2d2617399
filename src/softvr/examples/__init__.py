"""Runnable examples, one ``example_<topic>.py`` each with an ``Example`` class
(``__init__`` / ``step`` / ``render``) and a ``main(argv)`` taking ``--device``."""
