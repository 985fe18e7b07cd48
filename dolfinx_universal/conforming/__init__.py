"""Conform a background to a domain: classify, snap (M_h), relax, check, measure quality."""
