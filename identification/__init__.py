"""Parameter identification from exciter records (see issue 4)."""
