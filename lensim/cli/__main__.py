"""`python -m lensim.cli` runs the command line."""

from lensim.cli import main

main()
