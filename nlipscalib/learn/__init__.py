"""NLiPsNet: real-time normals from one tri-colour image (not built yet; see the issues)."""
