"""The documentation: the site builds, and every snippet runs."""
