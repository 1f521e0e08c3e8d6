"""RBA Studio's web app: FastAPI routes over the ``rba`` library, sessions in SQL, clips on disk."""
