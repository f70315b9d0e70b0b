"""`python -m cdpr` is the same as the `cdpr` command."""

from cdpr.tools.cli import main

if __name__ == "__main__":
    main()
