"""The real NLiPsTac sensor: LEDs over pyserial, camera through OpenCV."""
