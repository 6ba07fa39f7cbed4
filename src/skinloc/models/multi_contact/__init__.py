"""Multi-contact localisation: how many fingers touch one frame, and where (``contacts``)."""
