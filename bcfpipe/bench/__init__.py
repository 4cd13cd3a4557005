"""bcfpipe.bench."""
