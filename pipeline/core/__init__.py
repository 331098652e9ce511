"""Base layer: on-disk schema, atomic I/O, seeding, errors, records, stage keys, images. Imports nothing above it."""
