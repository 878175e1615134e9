"""One module per named agent."""
