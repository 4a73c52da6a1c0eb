"""Site catalog: pydantic records, YAML loading with line numbers, whole-catalog validation."""
