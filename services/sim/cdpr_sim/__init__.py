"""The sim service: DART physics of the platform and its cables, stepped on the clock's ticks."""
