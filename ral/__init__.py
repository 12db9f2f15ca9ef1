"""Robot Abstraction Layer: the GRI every robot shows ground stations, its task queue and link-loss failsafe,
and the ground-station client (``ral.gcs``).
Robot-independent: the manifest's task map says what a task needs.
"""
