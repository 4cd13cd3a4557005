"""bcfpipe.texset."""
