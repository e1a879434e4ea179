"""The Gradio app of ``lsr app`` (``app.ui`` layout, ``app.handlers`` callbacks, ``app.examples`` synthetic inputs).

Importing ``app`` loads nothing heavy; ``lsr app --weights DIR`` (or ``python -m app``) starts it.
"""
