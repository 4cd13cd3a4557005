"""`python -m bcfpipe` runs the command line."""
from .cli import main

main()
