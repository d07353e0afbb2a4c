"""``python -m loopid``: the same command line as the ``loopid`` console script."""

from loopid.cli import main

if __name__ == "__main__":
    main()
