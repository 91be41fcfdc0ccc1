"""The `aspod` command line: the entry point (`main`), one module per command, and the only code
that reads an `argparse.Namespace`."""
