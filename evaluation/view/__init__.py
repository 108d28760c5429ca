"""``whitted view``: an interactive viewer in the browser (``session``: camera, settings,
frozen frames, the side-by-side comparison with Mitsuba; ``server``: the page and its
websocket, aiohttp)."""
