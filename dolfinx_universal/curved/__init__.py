"""Curved cells: the maps G_h, I_h and their variants, with proven Jacobian bounds."""
