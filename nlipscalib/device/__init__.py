"""The real NLiPsTac sensor: LEDs over pyserial, camera through OpenCV.

``camera.open_source`` (a camera at fixed exposure, a video file or a folder of frames), ``controller.LedController``
and ``controller.lights_out_on_exit`` (the LED board, its LEDs dark when the block ends), ``adalight`` (a stock
Adalight board), ``virtual_board.start_board`` (an in-process board for trying without hardware), ``live.stream``
(frames through a predictor into sinks, as ``nlips live``), ``session`` (``nlips capture``'s presses).
"""
