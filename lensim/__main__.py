"""`python -m lensim ...`: the same command line as the `lensim` console script."""

from lensim.cli import main

if __name__ == "__main__":
    main()
