"""`python -m bcfpipe` runs the command line."""
from bcfpipe.cli import run

run()
