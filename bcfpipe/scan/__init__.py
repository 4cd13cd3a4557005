"""bcfpipe.scan."""
