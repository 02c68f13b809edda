"""Crazyflie logs: the uSD card's event-based log (the decoder, then the streams)."""
