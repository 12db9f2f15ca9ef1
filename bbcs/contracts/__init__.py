"""Cross-process types: what modules, the Module Manager, the RAL and ground stations exchange."""
