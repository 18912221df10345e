from bioslam.cli import console_main

console_main()
