"""Every ``lsr bench`` command, one module each (``bench_<command>``): each prints a table with the machine it ran on and
can write its section of BENCHMARKS.md (``lsr.eval.sections``). The top floor: it may run the app and the web page.
"""
