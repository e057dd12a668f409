"""The command-line programs: argparse and printing only; the work is in the library."""
