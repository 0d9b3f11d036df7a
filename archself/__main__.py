"""``python -m archself``: the same command line as the ``archself`` script."""

from archself.cli import main

if __name__ == "__main__":
    main()
