"""bcfpipe.train."""
