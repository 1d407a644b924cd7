"""Commissioning: the site description, the seal and compliance fits, node configs, deploy."""
