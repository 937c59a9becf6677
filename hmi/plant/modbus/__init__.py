"""A real plant over Modbus TCP, and the simulated plant served over it.

    client.py          ModbusPlant: the Plant contract over Modbus TCP
    link.py            one checked Modbus TCP connection (requests, answers, errors)
    frame.py           Modbus frames: building requests, checking answers
    tcp_server.py      a Modbus TCP server over asyncio
    address_map.py     inputs and outputs to Modbus tables and addresses, requests per scan
    link_log.py        connection events for the journal
    server.py          `plchmi serve-plant`: a SimPlant behind a Modbus TCP server
    server_process.py  that server in a child process (tests, bench)
"""
