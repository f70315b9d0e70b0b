"""Robot and scenario files: YAML checked by pydantic into the frozen objects of :mod:`cdpr.mechanics`.
An invalid file raises :class:`cdpr.errors.InputError` naming the file and the field."""
