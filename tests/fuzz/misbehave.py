"""A reader that misbehaves on request: the harness's own test (test_harness.py) checks that
each misbehaviour is classified as what it is."""

import os
import signal
import sys
import time

import numpy as np

from softvr.errors import InputError


def act(kind: str) -> None:
    if kind == "clean":
        raise InputError("body[2].tets", "a tet mesh", "garbage", source="/data/scene.toml")
    if kind == "traceback":
        raise KeyError("oops")
    if kind == "exit":
        sys.exit(1)
    if kind == "crash":
        os.kill(os.getpid(), signal.SIGSEGV)
    if kind == "hang":
        time.sleep(3600)
    if kind == "memory":
        np.ones(1 << 40, np.uint8)  # 1 TiB: beyond the address-space limit
    if kind == "rss":
        np.ones(400 << 20, np.uint8)  # 400 MiB touched: succeeds, but above the test's RSS limit
