"""The eyes: lids that follow the driver, irises where it looks, and the person's own eyes from an eye bank."""
