"""Generate: a configuration (filter, parameters, precision, prefix) resolved against its filter
folder, rendered through the emitter and the C templates into header, source and manifest."""
