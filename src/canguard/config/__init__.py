"""The YAML config: typed, frozen schema and loading with line numbers."""
