"""The kernel: recordings and their files, units, errors, the site, random streams, output folders. Imports nothing of the project above it."""
