"""bcfpipe.formats."""
