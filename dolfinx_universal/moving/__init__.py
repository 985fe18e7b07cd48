"""Moving domains on one background, and problems solved on them step after step."""
