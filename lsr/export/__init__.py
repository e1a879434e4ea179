"""``lsr export``: ONNX graphs (``graphs``: one wrapper module per graph), the torch-free bundle (``bundle``) and the
static web site (``web_site``).
"""
