"""The real NLiPsTac sensor: LEDs over pyserial, camera through OpenCV (not built yet; see the issues)."""
