"""One APIRouter per resource: domains, sessions, clips."""
