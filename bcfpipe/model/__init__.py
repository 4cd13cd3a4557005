"""bcfpipe.model."""
