"""The mouth: the inside of an open mouth, the nearest shot's mouth, its opening, and the person's own mouth from a mouth bank."""
