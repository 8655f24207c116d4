"""Placeholder removed when the subcommand lands."""
raise ImportError("not yet", name="omnican.cli.plot")
