"""A running session: the engine, its explanations and alarms, the journal, the runner.

    session.py          Session: the one door for commands; runs scans (virtual or real
                        time), explains each snapshot and keeps the alarms
    live.py             LiveRunner: a Session scanning in a thread against the wall clock
    journal_recorder.py JournalRecorder: operator actions and alarm transitions to the
                        journal, listening to a Session

What the UI, the command line and the OPC UA server (hmi/opcua/) all drive
(docs/architecture.md).
"""
