"""The ground floor: files written whole or not at all, YAML 1.2's core schema, the palette."""
