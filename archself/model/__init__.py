"""The data model of an architecture file (pydantic, the single source of truth), its loading
from YAML/JSON data with located errors, the JSON Schema generated from it, and synthetic files."""
