"""bcfpipe.export."""
