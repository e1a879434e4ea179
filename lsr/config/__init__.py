"""Typed configs: each dataclass is one ``lsr`` sub-command, and tyro turns it into the CLI.

``inference`` (reenact, demo, app, export, ...), ``eval_options``, ``train_options``, ``bench_options`` and
``bench_app_options``; all of them are importable from here (``from lsr.config import ReenactConfig``).
"""

from lsr.config.inference import *  # noqa: F401,F403
