"""Compile the NLP functions of README's worked example once (cold cache) and say how long it took.

Run in a folder holding README's ``fl_steer_stuck.toml``::

    OFFNOMINAL_CACHE=EMPTY_DIR /usr/bin/time -v nice python tests/bench/bench_compiled_nlp_compile.py
"""
import time
from dataclasses import replace
from offline.rover.table_builder import table_spec, _problem
s = table_spec("fl_steer_stuck.toml")
t = time.perf_counter()
pb = _problem(s.scenario, replace(s.solver, compile="on"))
print("problem with compiled functions in", round(time.perf_counter() - t, 1), "s wall;", pb._compiled is not None)
