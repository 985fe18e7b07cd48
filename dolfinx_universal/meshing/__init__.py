"""Mesh a domain from its boundary alone: size, conform, curve, certify, refine and retry."""
