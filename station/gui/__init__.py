"""The operator's Qt wizard (PySide6) over :class:`station.session.session.Session`.

``python app.py`` / ``python app.py gui [--simulate] [--config FILE]`` open it
(:func:`station.gui.app.main`). The session and everything below it import no
Qt (house style 8): this package talks to the one session object from worker
threads (:mod:`station.gui.worker`) and shows what it reports through Qt
signals (:mod:`station.gui.controller`); one module per wizard page under
:mod:`station.gui.pages`.
"""
