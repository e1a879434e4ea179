"""LSR: learned spatial representations for few-shot talking-head synthesis.

Nothing heavy is imported here: ``import lsr`` must stay cheap so the CLI and the
app start fast.
"""

__version__ = "0.1.0"
