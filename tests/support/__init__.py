"""What the tests share: helpers, a terminal, host processes, buses."""
