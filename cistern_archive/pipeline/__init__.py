"""The plugin pipeline: stage contracts, the entry-point registry and the runner."""
