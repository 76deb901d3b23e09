"""The C++ runtime that replays an exported World's step (C++17, the OpenCL C API).

``rbgen_host.hpp`` / ``rbgen_host.cpp``: `rbgen::Host`, shipped as package data so that a
C++ build finds it beside the installed rbgen (``DIR``); ``SCHEDULE.md``: the schedule
format it reads. ``examples/cpp`` builds ``rbgen_run`` from it with CMake.
"""

from pathlib import Path

#: the directory of the runtime's sources (CMake: -DRBGEN_HOST_DIR=...)
DIR = Path(__file__).parent
