"""bcfpipe.verify."""
