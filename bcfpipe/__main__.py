"""`python -m bcfpipe` runs the command line."""
from bcfpipe.cli import main

main()
