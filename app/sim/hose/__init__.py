"""Multi-body (lumped-mass) hose with its drogue, reel and coupling (issue 32)."""
