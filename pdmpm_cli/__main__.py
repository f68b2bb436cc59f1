from pdmpm_cli.cli.app import main

main()
